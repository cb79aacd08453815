//! Camera messages as the node receives them, validated and decoded into images: encoding,
//! layout and the size the camera's model takes. A rejected message carries the diagnostics
//! counter it increments and what exactly was wrong.

use super::diagnostics::BadImageReason;
use mode360_core::frame::RgbImage;
use mode360_core::geometry::RigCamera;
use mode360_io::msgs::image::{
    compressed_dimensions, rgb_from_compressed, rgb_from_image_msg, ImageMsgError,
};
use mode360_io::msgs::{CompressedImage, Image};

/// A received camera message.
pub(super) enum CameraMsg {
    Raw(Image),
    Compressed(CompressedImage),
}

/// A dropped camera message: why (the diagnostics counter) and what exactly.
pub(super) type Bad = (BadImageReason, String);

fn bad_image(e: ImageMsgError) -> Bad {
    (BadImageReason::from(&e), e.to_string())
}

/// Validates and decodes one camera message of `camera`: encoding, step and data length, and
/// the size its model takes (an ERP panorama 2:1 at any width, a fisheye or dual-fisheye
/// image exactly its `image_size`). A wrong size is [`BadImageReason::WrongSize`], with a
/// detail naming the camera, the size expected and the size received.
/// A compressed image's size is checked from its header before it is decoded, so a small
/// file that claims a huge image (a PNG or JPEG bomb) costs no memory.
pub(super) fn decode_camera(camera: &RigCamera, msg: &CameraMsg) -> Result<(u64, RgbImage), Bad> {
    let wrong_size = |e: mode360_core::geometry::ImageSizeError| {
        (
            BadImageReason::WrongSize,
            format!("camera '{}': {e}", camera.name),
        )
    };
    let (stamp_ns, image) = match msg {
        CameraMsg::Raw(m) => (
            m.header.stamp.to_nanos(),
            rgb_from_image_msg(m).map_err(bad_image)?,
        ),
        CameraMsg::Compressed(m) => {
            let (width, height) = compressed_dimensions(m).map_err(bad_image)?;
            camera
                .projection
                .check_image_size(width, height)
                .map_err(wrong_size)?;
            (
                m.header.stamp.to_nanos(),
                rgb_from_compressed(m).map_err(bad_image)?,
            )
        }
    };
    camera
        .projection
        .check_image_size(image.width(), image.height())
        .map_err(wrong_size)?;
    Ok((stamp_ns, image))
}

#[cfg(test)]
mod tests {
    use super::*;
    use mode360_core::geometry::Rig;
    use mode360_io::msgs::image::image_msg_from_rgb;
    use mode360_io::msgs::Header;

    const OMNIMVS_RIG: &str = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../launch_configs/rig_omnimvs.yaml"
    );
    const DUAL_RIG: &str = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../launch_configs/rig_dual_fisheye.yaml"
    );
    const DEEP360_RIG: &str = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../launch_configs/rig_deep360.yaml"
    );
    const STAMP_NS: u64 = 1_700_000_000_000_000_000;

    fn raw(width: u32, height: u32) -> CameraMsg {
        let img = RgbImage::from_pixel(width, height, image::Rgb([10, 20, 30]));
        CameraMsg::Raw(image_msg_from_rgb(Header::new(STAMP_NS, "cam"), &img))
    }

    fn png(width: u32, height: u32) -> CameraMsg {
        let img = RgbImage::from_pixel(width, height, image::Rgb([10, 20, 30]));
        let mut data = Vec::new();
        img.write_to(
            &mut std::io::Cursor::new(&mut data),
            image::ImageFormat::Png,
        )
        .expect("png");
        CameraMsg::Compressed(CompressedImage {
            header: Header::new(STAMP_NS, "cam"),
            format: "rgb8; png compressed bgr8".into(),
            data,
        })
    }

    #[test]
    fn fisheye_images_are_accepted_at_their_image_size_only() {
        let rig = Rig::from_file(OMNIMVS_RIG).expect("omnimvs rig");
        let cam = &rig.cameras[1];
        for msg in [raw(384, 384), png(384, 384)] {
            let (stamp_ns, img) = decode_camera(cam, &msg).expect("good fisheye image");
            assert_eq!((stamp_ns, img.dimensions()), (STAMP_NS, (384, 384)));
        }
        // A panorama, a half-size image and a transposed one are all dropped.
        for (w, h) in [(768, 384), (192, 192), (384, 383)] {
            for msg in [raw(w, h), png(w, h)] {
                let (reason, detail) = decode_camera(cam, &msg).expect_err("wrong size");
                assert_eq!(reason, BadImageReason::WrongSize);
                assert_eq!(reason.key(), "wrong_size");
                assert_eq!(
                    detail,
                    format!(
                        "camera 'front_right': expected 384x384 (its double_sphere image_size), got {w}x{h}"
                    )
                );
            }
        }
    }

    #[test]
    fn dual_fisheye_and_panorama_sizes() {
        let dual = Rig::from_file(DUAL_RIG).expect("dual rig");
        let cam = &dual.cameras[0];
        assert!(decode_camera(cam, &raw(512, 256)).is_ok());
        let (reason, detail) = decode_camera(cam, &raw(256, 256)).expect_err("one lens only");
        assert_eq!(reason, BadImageReason::WrongSize);
        assert_eq!(
            detail,
            "camera 'cam1': expected 512x256 (its dual_fisheye image_size), got 256x256"
        );
        // ERP cameras: any 2:1 size.
        let erp = Rig::from_file(DEEP360_RIG).expect("deep360 rig");
        let cam = &erp.cameras[2];
        for w in [64, 512, 1024] {
            assert!(decode_camera(cam, &raw(w, w / 2)).is_ok(), "{w}");
        }
        let (reason, detail) = decode_camera(cam, &png(384, 384)).expect_err("square");
        assert_eq!(reason, BadImageReason::WrongSize);
        assert_eq!(
            detail,
            "camera 'cam3': expected a 2:1 equirectangular panorama (width = 2 x height), got 384x384"
        );
    }
}
