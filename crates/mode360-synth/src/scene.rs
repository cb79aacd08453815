//! The per-frame scene the renderer traces: a BVH of primitives, an analytic ground plane
//! (the street's, a random-objects frame's, or none) and a background at infinity; shading
//! with sun, shadows, sky ambient, ground bounce and fog.

use super::bvh::{self, Bvh, PrimLabel, Ray};
use super::colour::Rgb;
use super::material::{self, Material};
use super::pattern::Background;
use super::sky::HORIZON_SKY;
use super::world::{self, WorldParams};
use mode360_core::frame::{SurfaceClass, NO_INSTANCE};
use nalgebra::Vector3;

/// Fog (aerial perspective) distance scale, metres.
pub const FOG_DISTANCE_M: f64 = 900.0;

/// World texture coordinates wrap along x with this period, metres, so that f32 texture
/// arithmetic keeps millimetre precision however far the rig drives (one seam per period).
pub const TEXTURE_WRAP_M: f64 = 2048.0;

/// Sun irradiance and sky ambient (linear RGB, for albedo 1).
const SUN_RADIANCE: Rgb = [1.55, 1.45, 1.3];
const SKY_AMBIENT: Rgb = [0.42, 0.48, 0.6];
/// Light bounced from the ground onto downward-facing surfaces.
const GROUND_BOUNCE: Rgb = [0.12, 0.11, 0.1];
/// Sky-ambient weight of a vertical surface (1 for an upward one, `2 base - 1` downward).
const SKY_VIEW_BASE: f64 = 0.6;
/// Ground-bounce weight of a vertical surface.
const GROUND_VIEW_SIDE: f64 = 0.3;
/// Light emitted by street-lamp heads (linear RGB added to the shaded colour).
const LAMP_EMISSION: Rgb = [0.3, 0.28, 0.2];
/// Offset of shadow-ray origins along the normal, metres.
const SHADOW_BIAS_M: f64 = 1e-4;
/// Footprints are divided by `max(|cos incidence|, MIN_COS_INCIDENCE)`.
const MIN_COS_INCIDENCE: f64 = 0.12;

/// One traced ray's result.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Sample {
    pub colour: Rgb,
    pub range_m: f64,
    pub label: PixelLabel,
}

/// What a ray met first, for the ground truth's labels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct PixelLabel {
    pub class: SurfaceClass,
    /// The object instance ([`NO_INSTANCE`] unless `class` is an object).
    pub instance: u16,
}

impl PixelLabel {
    const SKY: PixelLabel = PixelLabel {
        class: SurfaceClass::Sky,
        instance: NO_INSTANCE,
    };
}

/// The first surface a ray meets: its distance and the primitive (`None`: the ground plane).
#[derive(Clone, Copy, Debug)]
struct FirstHit {
    t: f64,
    prim: Option<bvh::PrimHit>,
}

/// The analytic ground plane of a frame.
pub(crate) enum Ground<'a> {
    /// The street's `z = 0` with its road, cross streets and grass.
    Street(&'a WorldParams),
    /// A plane `z = z_m` of one material (texture coordinates: world).
    Plane {
        z_m: f64,
        material: Material,
    },
    None,
}

/// The per-frame scene: primitives in a BVH plus the analytic ground plane and background.
pub(crate) struct FrameScene<'a> {
    pub bvh: Bvh<Material>,
    pub ground: Ground<'a>,
    pub background: Background,
    /// Unit vector towards the sun.
    pub sun_dir: Vector3<f64>,
    pub tex_seed: u32,
    pub pixel_angle_rad: f64,
    pub max_depth_m: f64,
    /// Render the sun's specular glare on glossy materials ([`material::gloss`]): it differs
    /// from camera to camera, as on real paint, glass and wet roads.
    pub specular: bool,
}

impl FrameScene<'_> {
    /// The first surface along `ray` (BVH primitive or ground plane), if any.
    fn first_hit(&self, ray: &Ray) -> Option<FirstHit> {
        let ground_z = match self.ground {
            Ground::Street(_) => Some(0.0),
            Ground::Plane { z_m, .. } => Some(z_m),
            Ground::None => None,
        };
        let t_ground = match ground_z {
            Some(z) if ray.dir.z < 0.0 => -(ray.origin.z - z) / ray.dir.z,
            _ => f64::INFINITY,
        };
        match self.bvh.closest(ray, t_ground) {
            Some(h) => Some(FirstHit {
                t: h.hit.t,
                prim: Some(h),
            }),
            None if t_ground.is_finite() => Some(FirstHit {
                t: t_ground,
                prim: None,
            }),
            None => None,
        }
    }

    /// The label of a first hit (`None`: the ray met nothing, the sky). Surfaces at or
    /// beyond the maximum depth are sky too, as their range is.
    fn label(&self, hit: Option<&FirstHit>) -> PixelLabel {
        let Some(hit) = hit.filter(|h| h.t < self.max_depth_m) else {
            return PixelLabel::SKY;
        };
        let (class, instance) = match hit.prim.map(|h| self.bvh.prims[h.prim].label) {
            None | Some(PrimLabel::Ground) => (SurfaceClass::Ground, NO_INSTANCE),
            Some(PrimLabel::Structure) => (SurfaceClass::Structure, NO_INSTANCE),
            Some(PrimLabel::Object(id)) => (SurfaceClass::Object, id),
        };
        PixelLabel { class, instance }
    }

    /// The range along `ray` (capped at the maximum depth) and what it met.
    pub fn range_and_label(&self, ray: &Ray) -> (f64, PixelLabel) {
        let hit = self.first_hit(ray);
        let range_m = hit
            .as_ref()
            .map_or(self.max_depth_m, |h| h.t.min(self.max_depth_m));
        (range_m, self.label(hit.as_ref()))
    }

    pub fn trace(&self, ray: &Ray) -> Sample {
        let seed = self.tex_seed;
        let sun = self.sun_dir;
        let first = self.first_hit(ray);
        let label = self.label(first.as_ref());
        let Some(FirstHit { t, prim: prim_hit }) = first else {
            return Sample {
                colour: self
                    .background
                    .colour(&ray.dir, &sun, self.pixel_angle_rad, seed),
                range_m: self.max_depth_m,
                label,
            };
        };
        let p = ray.at(t);
        let (material, mut n, p_obj) = match prim_hit {
            Some(h) => {
                let prim = &self.bvh.prims[h.prim];
                (prim.material, h.hit.normal, p - prim.object_origin)
            }
            None => match self.ground {
                Ground::Street(params) => {
                    let g = world::ground_material(params, &p);
                    (g.material, Vector3::z(), p - g.texture_origin)
                }
                Ground::Plane { material, .. } => (material, Vector3::z(), p),
                Ground::None => (Material::Concrete, Vector3::z(), p),
            },
        };
        let cos_in = n.dot(&ray.dir);
        if cos_in > 0.0 {
            n = -n;
        }
        let footprint_m = t * self.pixel_angle_rad / cos_in.abs().max(MIN_COS_INCIDENCE);
        let p_tex = Vector3::new(p.x.rem_euclid(TEXTURE_WRAP_M), p.y, p.z);
        let albedo = material::albedo(&material, &p_tex, &p_obj, &n, footprint_m, seed);
        let lambert = n.dot(&sun);
        let sunlit = if lambert > 0.0 {
            let shadow = Ray::new(p + n * SHADOW_BIAS_M, sun);
            if self.bvh.any(&shadow, f64::INFINITY) {
                0.0
            } else {
                lambert
            }
        } else {
            0.0
        };
        // Hemispherical ambient: the sky fills `(1 + n_z) / 2` of a surface's view (slightly
        // flattened), the ground the rest.
        let sky_w = SKY_VIEW_BASE + (1.0 - SKY_VIEW_BASE) * n.z;
        let ground_w = (-n.z).max(0.0) + GROUND_VIEW_SIDE * (1.0 - n.z.abs());
        let mut c = [0.0f32; 3];
        for i in 0..3 {
            c[i] = albedo[i]
                * (SUN_RADIANCE[i] * sunlit as f32
                    + SKY_AMBIENT[i] * sky_w as f32
                    + GROUND_BOUNCE[i] * ground_w as f32);
        }
        if self.specular && sunlit > 0.0 {
            if let Some((strength, exponent)) = material::gloss(&material) {
                // The sun mirrored in the surface, seen from the ray's origin.
                let mirrored = 2.0 * n.dot(&sun) * n - sun;
                let lobe = mirrored.dot(&-ray.dir).max(0.0).powi(exponent) as f32;
                for (ci, s) in c.iter_mut().zip(SUN_RADIANCE) {
                    *ci += strength * lobe * s;
                }
            }
        }
        if material == Material::Lamp {
            for (ci, e) in c.iter_mut().zip(LAMP_EMISSION) {
                *ci += e;
            }
        }
        // Aerial perspective towards the horizon sky colour.
        let fog = (1.0 - (-t / FOG_DISTANCE_M).exp()) as f32;
        for (ci, h) in c.iter_mut().zip(HORIZON_SKY) {
            *ci += (h - *ci) * fog;
        }
        Sample {
            colour: c,
            range_m: t.min(self.max_depth_m),
            label,
        }
    }
}
