//! Blocked lenses: something opaque covers a given fraction of one camera's view and stays
//! there in every frame. Three kinds ([`BlockerKind`]): mud (a ragged brown slab on the lens),
//! a mount (a dark pole rising from the bottom of the view with a bracket arm) and a vehicle
//! part (a body panel filling the lower part of the view).
//!
//! * Shapes live on the camera's sphere of view directions, in a *view frame*: for ERP and
//!   dual-fisheye cameras the camera frame (x forward, z up), for a single fisheye the optical
//!   frame turned so that forward is the optical axis and up is the image's top (`-y`).
//!   Latitude `lat = asin(up . d)`, longitude `lon = atan2(left . d, forward . d)`.
//! * Each shape is a family of regions growing with one size `s`: every pixel has the smallest
//!   `s*` that covers it ([`Blocker::threshold`]). Mud: `s* = angle(d, c) / (1 + MUD_RAGGEDNESS
//!   n(d))` (a cap around `c` with a noisy rim, `n` in `[-1, 1]`); mount: the pole is
//!   `lat <= lat_top` and `|lon - lon0| <= s`, the bracket `|lat - lat_top| <= s
//!   BRACKET_THICKNESS_RATIO` along the arm; vehicle: `|lon - lon_c| <= H` and
//!   `lat <= s - drop ((lon - lon_c) / H)^2`.
//! * Size: the fraction of the view is measured with weights, `cos(lat)` per ERP pixel (solid
//!   angle) and 1 per seen fisheye pixel (pixels the lens does not see weigh 0 and stay
//!   black). Pixels sorted by `s*` are taken until the weighted fraction is nearest the
//!   target, so the mask hits the target to within one group of equal `s*` (at most a column
//!   of a mount's pole), and the reported fraction is the mask's, exactly.
//! * Painting: blocked pixels get the blocker's colour (a function of the view direction, not
//!   of the scene); every other pixel keeps its bytes.
//! * The shape's placement is drawn from `Rng::new(&[world_seed, camera, kind, BLOCKER_TAG])`:
//!   fixed across frames, and the same for every target fraction.

use super::camera_view::PixelRays;
use super::noise::{value3, Rng};
use mode360_core::frame::RgbImage;
use mode360_core::geometry::Projection;
use std::f64::consts::{FRAC_PI_2, PI};

/// Largest target fraction of a blocker (every kind reaches it on ERP and fisheye images).
pub const MAX_BLOCKED_FRACTION: f64 = 0.6;
/// Amplitude of the mud rim's noise, relative to the cap's radius.
pub const MUD_RAGGEDNESS: f64 = 0.3;
/// Frequency of the mud rim's noise, cycles per radian of view direction.
const MUD_RIM_FREQ_PER_RAD: f32 = 2.5;
/// Mud centre: within this latitude of the horizon, and on a single fisheye within
/// [`NARROW_FIELD_MAX_LON_RAD`] of the optical axis.
pub const MUD_MAX_CENTRE_LAT_RAD: f64 = 40.0 * PI / 180.0;
/// Longitude range of shape centres on a single fisheye (its field is one hemisphere or so).
pub const NARROW_FIELD_MAX_LON_RAD: f64 = 45.0 * PI / 180.0;
/// Top of a mount's pole (where the bracket arm is), latitude.
pub const MOUNT_MIN_TOP_LAT_RAD: f64 = 15.0 * PI / 180.0;
pub const MOUNT_MAX_TOP_LAT_RAD: f64 = 35.0 * PI / 180.0;
/// Length of a mount's bracket arm, longitude.
pub const MOUNT_MIN_ARM_RAD: f64 = 20.0 * PI / 180.0;
pub const MOUNT_MAX_ARM_RAD: f64 = 50.0 * PI / 180.0;
/// Half thickness of the bracket relative to the pole's half width.
pub const BRACKET_THICKNESS_RATIO: f64 = 0.4;
/// Half span `H` of a vehicle panel in longitude.
pub const VEHICLE_MIN_HALF_SPAN_RAD: f64 = 130.0 * PI / 180.0;
pub const VEHICLE_MAX_HALF_SPAN_RAD: f64 = PI;
/// How far a vehicle panel's top edge drops at the ends of its span, latitude.
pub const VEHICLE_MIN_DROP_RAD: f64 = 10.0 * PI / 180.0;
pub const VEHICLE_MAX_DROP_RAD: f64 = 30.0 * PI / 180.0;
/// Domain separation of the blocker shapes.
const BLOCKER_TAG: u64 = 0xB10C_0001;

/// What blocks a lens.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize,
)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "snake_case")]
pub enum BlockerKind {
    /// A ragged brown slab of mud on the lens.
    #[default]
    Mud,
    /// A dark pole and bracket (a mount) rising from the bottom of the view.
    Mount,
    /// A body panel of the vehicle filling the lower part of the view.
    Vehicle,
}

impl BlockerKind {
    pub const ALL: [BlockerKind; 3] = [BlockerKind::Mud, BlockerKind::Mount, BlockerKind::Vehicle];

    pub fn as_str(self) -> &'static str {
        match self {
            BlockerKind::Mud => "mud",
            BlockerKind::Mount => "mount",
            BlockerKind::Vehicle => "vehicle",
        }
    }
}

/// Errors of a blocker specification; each names the camera or the text at fault.
#[derive(Debug, thiserror::Error)]
pub enum BlockerError {
    #[error("blocked lens of camera {camera}: fraction must be in (0, {MAX_BLOCKED_FRACTION}], got {value}")]
    Fraction { camera: String, value: f64 },
    #[error("blocked lens of camera {camera} given twice")]
    DuplicateCamera { camera: String },
    #[error("blocked lens '{spec}': {problem}")]
    Spec { spec: String, problem: String },
}

/// One blocked camera: `fraction` of its view (see the module docs) covered by `kind`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BlockedLens {
    /// Camera index in rig order (0-based).
    pub camera: usize,
    /// Target fraction of the camera's view, in `(0, MAX_BLOCKED_FRACTION]`.
    pub fraction: f64,
    pub kind: BlockerKind,
}

impl BlockedLens {
    /// `CAM:FRACTION:KIND` with the 1-based camera index (the `--blocked-lens` syntax).
    pub fn to_spec(&self) -> String {
        format!(
            "{}:{}:{}",
            self.camera + 1,
            self.fraction,
            self.kind.as_str()
        )
    }

    /// Checks the fraction; names the camera (1-based) when it is out of range.
    pub fn validate(&self) -> Result<(), BlockerError> {
        if !(self.fraction > 0.0 && self.fraction <= MAX_BLOCKED_FRACTION) {
            return Err(BlockerError::Fraction {
                camera: (self.camera + 1).to_string(),
                value: self.fraction,
            });
        }
        Ok(())
    }
}

/// Checks every blocker and that no camera is blocked twice.
pub fn validate_blockers(blockers: &[BlockedLens]) -> Result<(), BlockerError> {
    for (k, b) in blockers.iter().enumerate() {
        b.validate()?;
        if blockers[..k].iter().any(|o| o.camera == b.camera) {
            return Err(BlockerError::DuplicateCamera {
                camera: (b.camera + 1).to_string(),
            });
        }
    }
    Ok(())
}

/// Parses `CAM:FRACTION[:KIND]` (CAM a camera name or 1-based index into `camera_names`,
/// KIND `mud`, `mount` or `vehicle`, default mud).
pub fn parse_blocked_lens(spec: &str, camera_names: &[&str]) -> Result<BlockedLens, BlockerError> {
    let bad = |problem: String| BlockerError::Spec {
        spec: spec.to_string(),
        problem,
    };
    let parts: Vec<&str> = spec.split(':').collect();
    if !(2..=3).contains(&parts.len()) {
        return Err(bad("expected CAM:FRACTION[:KIND]".into()));
    }
    let cam = parts[0].trim();
    let camera = match camera_names.iter().position(|n| *n == cam) {
        Some(i) => i,
        None => match cam.parse::<usize>() {
            Ok(i) if (1..=camera_names.len()).contains(&i) => i - 1,
            _ => {
                return Err(bad(format!(
                    "camera '{cam}' is neither a camera name nor an index 1..={} (cameras: {})",
                    camera_names.len(),
                    camera_names.join(", ")
                )))
            }
        },
    };
    let fraction: f64 = parts[1]
        .trim()
        .parse()
        .map_err(|_| bad(format!("fraction '{}' is not a number", parts[1])))?;
    let kind = match parts.get(2).map(|k| k.trim()) {
        None => BlockerKind::Mud,
        Some(k) => BlockerKind::ALL
            .into_iter()
            .find(|b| b.as_str() == k)
            .ok_or_else(|| bad(format!("kind '{k}' is not one of mud, mount, vehicle")))?,
    };
    let lens = BlockedLens {
        camera,
        fraction,
        kind,
    };
    lens.validate().map_err(|_| {
        bad(format!(
            "fraction {fraction} must be in (0, {MAX_BLOCKED_FRACTION}]"
        ))
    })?;
    Ok(lens)
}

/// Where every pixel of one camera image looks, in the view frame, and what it weighs.
#[derive(Clone, Debug)]
pub struct LensGeometry {
    pub width: usize,
    pub height: usize,
    /// `(lat, lon)` per pixel (row-major); `None` where the lens sees nothing.
    view: Vec<Option<(f64, f64)>>,
    /// Solid-angle weight per pixel: `cos(lat)` on a panorama, 1 or 0 on a fisheye.
    weight: Vec<f64>,
    /// A single fisheye: shapes are centred near the optical axis.
    narrow_field: bool,
}

impl LensGeometry {
    /// An ERP panorama of `width x height` pixels.
    pub fn panorama(width: usize, height: usize) -> Self {
        let mut view = Vec::with_capacity(width * height);
        let mut weight = Vec::with_capacity(width * height);
        for v in 0..height {
            let lat = FRAC_PI_2 - PI * (v as f64 + 0.5) / height as f64;
            for u in 0..width {
                let lon = PI * (1.0 - 2.0 * (u as f64 + 0.5) / width as f64);
                view.push(Some((lat, lon)));
                weight.push(lat.cos());
            }
        }
        Self {
            width,
            height,
            view,
            weight,
            narrow_field: false,
        }
    }

    /// A fisheye or dual-fisheye image from its pixel rays; `optical` for a single fisheye,
    /// whose camera frame is its optical frame (z forward, y down).
    pub fn of_rays(rays: &PixelRays, optical: bool) -> Self {
        let (width, height) = (rays.width, rays.height);
        let mut view = Vec::with_capacity(width * height);
        for v in 0..height {
            for u in 0..width {
                view.push(rays.get(u, v).map(|r| {
                    let d = r.dir.normalize();
                    let (fwd, left, up) = if optical {
                        (d.z, -d.x, -d.y)
                    } else {
                        (d.x, d.y, d.z)
                    };
                    (up.clamp(-1.0, 1.0).asin(), left.atan2(fwd))
                }));
            }
        }
        let weight = view
            .iter()
            .map(|p| f64::from(u8::from(p.is_some())))
            .collect();
        Self {
            width,
            height,
            view,
            weight,
            narrow_field: optical,
        }
    }

    /// The geometry of a camera with `projection`, ERP images being `erp_width` wide.
    pub fn of_projection(projection: &Projection, erp_width: usize) -> Self {
        match PixelRays::of_projection(projection) {
            None => Self::panorama(erp_width, erp_width / 2),
            Some(rays) => Self::of_rays(&rays, matches!(projection, Projection::Fisheye(_))),
        }
    }
}

/// A blocker's placement (drawn once per world, camera and kind).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Blocker {
    pub kind: BlockerKind,
    /// Mud: cap centre; mount: pole longitude and top; vehicle: panel centre longitude.
    centre_lat: f64,
    centre_lon: f64,
    /// Mount: signed arm length; vehicle: half span.
    span: f64,
    /// Vehicle: drop of the top edge at the span's ends.
    drop: f64,
    seed: u32,
    colour: [f64; 3],
}

fn wrap_angle(a: f64) -> f64 {
    (a + PI).rem_euclid(2.0 * PI) - PI
}

fn unit_dir(lat: f64, lon: f64) -> [f64; 3] {
    [lat.cos() * lon.cos(), lat.cos() * lon.sin(), lat.sin()]
}

/// Car paints of vehicle panels (white, silver, black, red, blue), linear 0..255.
const PAINTS: [[f64; 3]; 5] = [
    [215.0, 215.0, 210.0],
    [150.0, 152.0, 155.0],
    [28.0, 28.0, 32.0],
    [150.0, 25.0, 22.0],
    [30.0, 50.0, 120.0],
];

impl Blocker {
    /// The blocker `kind` of camera `camera` in world `world_seed`, placed for `geometry`.
    pub fn draw(
        kind: BlockerKind,
        world_seed: u64,
        camera: usize,
        geometry: &LensGeometry,
    ) -> Self {
        let mut rng = Rng::new(&[world_seed, camera as u64, kind as u64, BLOCKER_TAG]);
        let lon_range = if geometry.narrow_field {
            NARROW_FIELD_MAX_LON_RAD
        } else {
            PI
        };
        let centre_lon = rng.range(-lon_range, lon_range);
        let seed = (rng.next_u64() >> 32) as u32;
        match kind {
            BlockerKind::Mud => Self {
                kind,
                centre_lat: rng.range(-MUD_MAX_CENTRE_LAT_RAD, MUD_MAX_CENTRE_LAT_RAD),
                centre_lon,
                span: 0.0,
                drop: 0.0,
                seed,
                colour: [
                    rng.range(0.22, 0.36) * 255.0,
                    rng.range(0.15, 0.24) * 255.0,
                    rng.range(0.08, 0.13) * 255.0,
                ],
            },
            BlockerKind::Mount => {
                let grey = rng.range(30.0, 60.0);
                let arm = rng.range(MOUNT_MIN_ARM_RAD, MOUNT_MAX_ARM_RAD);
                Self {
                    kind,
                    centre_lat: rng.range(MOUNT_MIN_TOP_LAT_RAD, MOUNT_MAX_TOP_LAT_RAD),
                    centre_lon,
                    span: if rng.chance(0.5) { arm } else { -arm },
                    drop: 0.0,
                    seed,
                    colour: [grey, grey, grey * 1.08],
                }
            }
            BlockerKind::Vehicle => Self {
                kind,
                centre_lat: 0.0,
                centre_lon,
                span: rng.range(VEHICLE_MIN_HALF_SPAN_RAD, VEHICLE_MAX_HALF_SPAN_RAD),
                drop: rng.range(VEHICLE_MIN_DROP_RAD, VEHICLE_MAX_DROP_RAD),
                seed,
                colour: PAINTS[rng.index(PAINTS.len())],
            },
        }
    }

    /// Noise in `[-1, 1]` of the view direction `(lat, lon)`, smooth across the seam.
    fn noise(&self, lat: f64, lon: f64, freq: f32, seed: u32) -> f64 {
        let [x, y, z] = unit_dir(lat, lon).map(|c| c as f32 * freq);
        2.0 * f64::from(value3(x, y, z, seed)) - 1.0
    }

    /// The smallest size that covers view direction `(lat, lon)` (`INFINITY`: none).
    pub fn threshold(&self, lat: f64, lon: f64) -> f64 {
        let dlon = wrap_angle(lon - self.centre_lon);
        match self.kind {
            BlockerKind::Mud => {
                let [a, b] = [
                    unit_dir(lat, lon),
                    unit_dir(self.centre_lat, self.centre_lon),
                ];
                let cos = (a[0] * b[0] + a[1] * b[1] + a[2] * b[2]).clamp(-1.0, 1.0);
                let rim =
                    1.0 + MUD_RAGGEDNESS * self.noise(lat, lon, MUD_RIM_FREQ_PER_RAD, self.seed);
                cos.acos() / rim
            }
            BlockerKind::Mount => {
                let pole = if lat <= self.centre_lat {
                    dlon.abs()
                } else {
                    f64::INFINITY
                };
                let along = dlon * self.span.signum();
                let bracket = if (0.0..=self.span.abs()).contains(&along) {
                    (lat - self.centre_lat).abs() / BRACKET_THICKNESS_RATIO
                } else {
                    f64::INFINITY
                };
                pole.min(bracket)
            }
            BlockerKind::Vehicle => {
                if dlon.abs() > self.span {
                    f64::INFINITY
                } else {
                    // Sizes start at 0 for the lowest latitude, so thresholds are >= 0.
                    lat + FRAC_PI_2 + self.drop * (dlon / self.span).powi(2)
                }
            }
        }
    }

    /// Colour of a blocked pixel looking along `(lat, lon)` for a blocker of size `size`.
    fn colour_at(&self, lat: f64, lon: f64, size: f64) -> [u8; 3] {
        let dlon = wrap_angle(lon - self.centre_lon);
        let shade = match self.kind {
            BlockerKind::Mud => {
                let grain = 0.85 + 0.25 * self.noise(lat, lon, 40.0, self.seed ^ 1);
                // Thicker (darker) towards the middle of the slab.
                let depth = (self.threshold(lat, lon) / size.max(1e-9)).clamp(0.0, 1.0);
                grain * (0.8 + 0.25 * depth)
            }
            BlockerKind::Mount => {
                // A round pole: lit on one side, dark at the rims.
                let x = if lat <= self.centre_lat {
                    (dlon / size.max(1e-9)).clamp(-1.0, 1.0)
                } else {
                    0.3
                };
                0.55 + 0.55 * (1.0 - x * x).sqrt() + 0.15 * x
            }
            BlockerKind::Vehicle => {
                let edge = size - FRAC_PI_2 - self.drop * (dlon / self.span).powi(2);
                let below = (edge - lat).max(0.0);
                // A bright reflection along the top edge, darker towards the bottom.
                let rim = if below < 0.04 { 1.35 } else { 1.0 };
                rim * (0.55 + 0.45 * (1.0 - below / PI))
                    + 0.05 * self.noise(lat, lon, 6.0, self.seed)
            }
        };
        self.colour
            .map(|c| (c * shade).round().clamp(0.0, 255.0) as u8)
    }
}

/// Which pixels a blocker covers and the fraction of the view they make up.
#[derive(Clone, Debug, PartialEq)]
pub struct BlockerMask {
    pub width: usize,
    pub height: usize,
    /// `true` for blocked pixels (row-major).
    pub mask: Vec<bool>,
    /// Weighted fraction of the view the mask covers (see the module docs), exact.
    pub fraction: f64,
    /// The blocker's size `s` that gives the mask.
    size: f64,
}

/// The mask of `blocker` on `geometry` nearest to `target` (a fraction of the view).
pub fn blocker_mask(blocker: &Blocker, geometry: &LensGeometry, target: f64) -> BlockerMask {
    let thresholds: Vec<f64> = geometry
        .view
        .iter()
        .map(|p| p.map_or(f64::INFINITY, |(lat, lon)| blocker.threshold(lat, lon)))
        .collect();
    let total: f64 = geometry.weight.iter().sum();
    let mut order: Vec<usize> = (0..thresholds.len())
        .filter(|&i| thresholds[i].is_finite() && geometry.weight[i] > 0.0)
        .collect();
    order.sort_by(|&a, &b| thresholds[a].total_cmp(&thresholds[b]));
    // Take whole groups of equal thresholds while that brings the fraction nearer the target.
    let (mut size, mut best_err, mut acc) = (f64::NEG_INFINITY, target.abs(), 0.0);
    for (k, &i) in order.iter().enumerate() {
        acc += geometry.weight[i];
        let group_end = order
            .get(k + 1)
            .is_none_or(|&j| thresholds[j] > thresholds[i]);
        if !group_end || total <= 0.0 {
            continue;
        }
        let err = (acc / total - target).abs();
        if err <= best_err {
            best_err = err;
            size = thresholds[i];
        } else if acc / total > target {
            break;
        }
    }
    let mask: Vec<bool> = thresholds.iter().map(|&t| t <= size).collect();
    let covered: f64 = mask
        .iter()
        .zip(&geometry.weight)
        .filter(|(m, _)| **m)
        .map(|(_, w)| w)
        .sum();
    BlockerMask {
        width: geometry.width,
        height: geometry.height,
        mask,
        fraction: if total > 0.0 { covered / total } else { 0.0 },
        size,
    }
}

/// Paints `blocker` over the masked pixels of `img` (of `geometry`'s size); other pixels keep
/// their bytes. An image of another size is left alone.
pub fn paint_blocker(
    img: &mut RgbImage,
    geometry: &LensGeometry,
    blocker: &Blocker,
    mask: &BlockerMask,
) {
    let (w, h) = (img.width() as usize, img.height() as usize);
    if (w, h) != (geometry.width, geometry.height) || mask.mask.len() != w * h {
        return;
    }
    for (i, _) in mask.mask.iter().enumerate().filter(|(_, m)| **m) {
        if let Some((lat, lon)) = geometry.view[i] {
            let c = blocker.colour_at(lat, lon, mask.size);
            img.put_pixel((i % w) as u32, (i / w) as u32, image::Rgb(c));
        }
    }
}

/// The mask `lens` gives on a camera of `projection` (ERP images `erp_width` wide) in world
/// `world_seed`.
pub fn lens_mask(
    lens: &BlockedLens,
    projection: &Projection,
    erp_width: usize,
    world_seed: u64,
) -> BlockerMask {
    let geometry = LensGeometry::of_projection(projection, erp_width);
    let blocker = Blocker::draw(lens.kind, world_seed, lens.camera, &geometry);
    blocker_mask(&blocker, &geometry, lens.fraction)
}

/// Blocks `img` (the image of camera `lens.camera` with `projection`) as `lens` says, in world
/// `world_seed`; returns the blocked fraction of its view.
pub fn block_image(
    img: &mut RgbImage,
    projection: &Projection,
    lens: &BlockedLens,
    world_seed: u64,
) -> f64 {
    let geometry = match PixelRays::of_projection(projection) {
        None => LensGeometry::panorama(img.width() as usize, img.height() as usize),
        Some(rays) => LensGeometry::of_rays(&rays, matches!(projection, Projection::Fisheye(_))),
    };
    let blocker = Blocker::draw(lens.kind, world_seed, lens.camera, &geometry);
    let mask = blocker_mask(&blocker, &geometry, lens.fraction);
    paint_blocker(img, &geometry, &blocker, &mask);
    mask.fraction
}
