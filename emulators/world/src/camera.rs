//! The simulated camera: its optics and sensor (a TOML file under `config/cameras/`), and
//! the exact geometric mapping between board millimetres and image pixels.
//!
//! Geometry (this is the truth the localizer must recover, never read by the gateway):
//! * pixel coordinates: x right, y down, integer = pixel centre, image centre
//!   c = ((W-1)/2, (H-1)/2);
//! * the image centre looks at board point `pose.centre_mm` (the tool point);
//! * the image +x axis points along board direction (cos t, sin t) and image +y along
//!   (sin t, -cos t), with t = rotation_deg + pose.rotation_rad (a camera above the board
//!   looking down: image rows go towards board -y). `mirrored` flips image y (a camera
//!   looking up at the board from below);
//! * radial distortion about c: a point at undistorted radius r moves outward to
//!   r (1 + k r^2), with k chosen so the frame corner moves by `distortion_px_at_corner`.

use protocol::config::{ConfigDoc, ConfigError};
use serde::Deserialize;
use std::path::Path;

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CameraModel {
    #[serde(default = "default_model_name")]
    pub model: String,
    pub width: u32,
    pub height: u32,
    /// 8 or 16.
    pub bit_depth: u8,
    /// Object-space pixel size (micrometres on the board per pixel).
    pub um_per_px: f64,
    /// Mount rotation of the image x axis against board +x, degrees, counter-clockwise.
    #[serde(default)]
    pub rotation_deg: f64,
    #[serde(default)]
    pub mirrored: bool,
    /// Radial displacement at the frame corner, pixels (positive = barrel outward).
    #[serde(default)]
    pub distortion_px_at_corner: f64,
    /// Gaussian optical blur, sigma in pixels.
    #[serde(default)]
    pub blur_sigma_px: f64,
    /// Sensor noise, sigma in grey levels of the output bit depth.
    #[serde(default)]
    pub noise_sigma: f64,
    /// Plate (background) reflectance as a fraction of full scale.
    pub background_level: f64,
    /// Dot reflectance as a fraction of full scale.
    pub dot_level: f64,
    /// Relative illumination change from frame centre to the edge along `illumination_angle_deg`.
    #[serde(default)]
    pub illumination_gradient: f64,
    #[serde(default)]
    pub illumination_angle_deg: f64,
    /// Relative illumination fall-off at the frame corner (cos^4-like, modelled as r^2).
    #[serde(default)]
    pub vignetting: f64,
}

fn default_model_name() -> String {
    "simulated mono camera".to_string()
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraFile {
    camera: CameraModel,
}

/// Where the camera really is: the board point at the image centre and any extra
/// rotation (stage yaw) on top of the mount rotation.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct CameraPose {
    pub centre_mm: [f64; 2],
    pub rotation_rad: f64,
}

impl CameraModel {
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        Self::from_doc(&ConfigDoc::read(path)?)
    }

    pub fn from_doc(doc: &ConfigDoc) -> Result<Self, ConfigError> {
        let m = doc.parse::<CameraFile>()?.camera;
        let bad = |k: &str, msg: &str| doc.invalid(&format!("camera.{k}"), msg);
        if m.width < 16 || m.height < 16 || m.width > 8192 || m.height > 8192 {
            return Err(bad("width", "frame size must be 16..8192 pixels each way"));
        }
        if m.bit_depth != 8 && m.bit_depth != 16 {
            return Err(bad("bit_depth", "must be 8 or 16"));
        }
        let key = |k: &str| format!("camera.{k}");
        doc.positive(&key("um_per_px"), m.um_per_px, 1000.0, "um/px")?;
        doc.in_range(&key("rotation_deg"), m.rotation_deg, -360.0, 360.0, "deg")?;
        doc.in_range(
            &key("distortion_px_at_corner"),
            m.distortion_px_at_corner,
            -100.0,
            100.0,
            "px",
        )?;
        // Rendering cost grows with the kernel (about 6 sigma): 20 px is already a frame
        // no localizer can use, and 1e5 px would render for minutes.
        doc.in_range(&key("blur_sigma_px"), m.blur_sigma_px, 0.0, 20.0, "px")?;
        let full_scale = if m.bit_depth == 8 { 255.0 } else { 65535.0 };
        doc.in_range(
            &key("noise_sigma"),
            m.noise_sigma,
            0.0,
            (full_scale / 4.0_f64).floor(),
            "grey levels",
        )?;
        for k in ["background_level", "dot_level"] {
            let v = if k == "dot_level" {
                m.dot_level
            } else {
                m.background_level
            };
            doc.in_range(&key(k), v, 0.0, 1.0, "of full scale")?;
        }
        if (m.background_level - m.dot_level).abs() < 0.05 {
            return Err(bad(
                "dot_level",
                "dots need at least 5 % contrast against the background",
            ));
        }
        doc.in_range(
            &key("illumination_gradient"),
            m.illumination_gradient,
            -1.0,
            1.0,
            "",
        )?;
        doc.in_range(
            &key("illumination_angle_deg"),
            m.illumination_angle_deg,
            -360.0,
            360.0,
            "deg",
        )?;
        doc.in_range(&key("vignetting"), m.vignetting, 0.0, 1.0, "")?;
        Ok(m)
    }

    pub fn centre(&self) -> [f64; 2] {
        [
            (self.width as f64 - 1.0) / 2.0,
            (self.height as f64 - 1.0) / 2.0,
        ]
    }

    fn corner_radius(&self) -> f64 {
        let c = self.centre();
        (c[0] * c[0] + c[1] * c[1]).sqrt()
    }

    /// Distortion coefficient k of r -> r (1 + k r^2), r in pixels.
    pub fn distortion_k(&self) -> f64 {
        let rc = self.corner_radius();
        self.distortion_px_at_corner / (rc * rc * rc)
    }

    fn axes(&self, pose: &CameraPose) -> ([f64; 2], [f64; 2]) {
        let t = self.rotation_deg.to_radians() + pose.rotation_rad;
        let (s, c) = t.sin_cos();
        let ex = [c, s];
        let ey = if self.mirrored { [-s, c] } else { [s, -c] };
        (ex, ey)
    }

    /// Board millimetres -> distorted image pixels.
    pub fn board_to_pixel(&self, pose: &CameraPose, b: [f64; 2]) -> [f64; 2] {
        let (ex, ey) = self.axes(pose);
        let v = [b[0] - pose.centre_mm[0], b[1] - pose.centre_mm[1]];
        let s = self.um_per_px / 1000.0;
        let d = [
            (v[0] * ex[0] + v[1] * ex[1]) / s,
            (v[0] * ey[0] + v[1] * ey[1]) / s,
        ];
        let f = 1.0 + self.distortion_k() * (d[0] * d[0] + d[1] * d[1]);
        let c = self.centre();
        [c[0] + d[0] * f, c[1] + d[1] * f]
    }

    /// Distorted image pixels -> board millimetres (inverse of [`Self::board_to_pixel`]).
    pub fn pixel_to_board(&self, pose: &CameraPose, p: [f64; 2]) -> [f64; 2] {
        let c = self.centre();
        let dd = [p[0] - c[0], p[1] - c[1]];
        let rd = (dd[0] * dd[0] + dd[1] * dd[1]).sqrt();
        // Solve r (1 + k r^2) = rd by Newton; converges in a few steps for small k.
        let k = self.distortion_k();
        let mut r = rd;
        for _ in 0..8 {
            let f = r * (1.0 + k * r * r) - rd;
            let df = 1.0 + 3.0 * k * r * r;
            r -= f / df;
        }
        let scale = if rd > 0.0 { r / rd } else { 1.0 };
        let d = [dd[0] * scale, dd[1] * scale];
        let (ex, ey) = self.axes(pose);
        let s = self.um_per_px / 1000.0;
        [
            pose.centre_mm[0] + s * (d[0] * ex[0] + d[1] * ey[0]),
            pose.centre_mm[1] + s * (d[0] * ex[1] + d[1] * ey[1]),
        ]
    }

    /// Field of view in millimetres (width, height).
    pub fn field_of_view_mm(&self) -> [f64; 2] {
        [
            self.width as f64 * self.um_per_px / 1000.0,
            self.height as f64 * self.um_per_px / 1000.0,
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(crate) fn model() -> CameraModel {
        CameraModel {
            model: "t".into(),
            width: 1280,
            height: 1024,
            bit_depth: 8,
            um_per_px: 4.0,
            rotation_deg: 1.5,
            mirrored: false,
            distortion_px_at_corner: 1.6,
            blur_sigma_px: 1.0,
            noise_sigma: 2.0,
            background_level: 0.8,
            dot_level: 0.15,
            illumination_gradient: 0.1,
            illumination_angle_deg: 20.0,
            vignetting: 0.05,
        }
    }

    fn load_with(from: &str, to: &str) -> Result<CameraModel, ConfigError> {
        let text = include_str!("../../../config/cameras/mono-1.3mp.toml");
        assert!(text.contains(from), "{from}");
        let text = text.replacen(from, to, 1);
        CameraModel::from_doc(&ConfigDoc::from_text("c.toml", &text, Path::new(".")))
    }

    #[test]
    fn non_finite_and_unphysical_optics_are_refused_at_load_naming_key_and_range() {
        let cases = [
            (
                "blur_sigma_px = 1.0",
                "blur_sigma_px = 1e5",
                "camera.blur_sigma_px",
            ),
            (
                "blur_sigma_px = 1.0",
                "blur_sigma_px = nan",
                "camera.blur_sigma_px",
            ),
            (
                "noise_sigma = 2.0",
                "noise_sigma = inf",
                "camera.noise_sigma",
            ),
            (
                "noise_sigma = 2.0",
                "noise_sigma = 1000.0",
                "camera.noise_sigma",
            ),
            ("um_per_px = 4.0", "um_per_px = 1e12", "camera.um_per_px"),
            (
                "rotation_deg = 0.8",
                "rotation_deg = nan",
                "camera.rotation_deg",
            ),
            (
                "distortion_px_at_corner = 0.8",
                "distortion_px_at_corner = inf",
                "camera.distortion_px_at_corner",
            ),
            ("dot_level = 0.12", "dot_level = nan", "camera.dot_level"),
            (
                "illumination_gradient = 0.12",
                "illumination_gradient = nan",
                "camera.illumination_gradient",
            ),
            (
                "illumination_angle_deg = 30.0",
                "illumination_angle_deg = inf",
                "camera.illumination_angle_deg",
            ),
            ("vignetting = 0.05", "vignetting = nan", "camera.vignetting"),
            ("vignetting = 0.05", "vignetting = 7.0", "camera.vignetting"),
        ];
        for (from, to, key) in cases {
            let e = load_with(from, to).unwrap_err().to_string();
            assert!(e.contains(&format!("key `{key}`")), "{to}: {e}");
            assert!(e.contains("..="), "{to}: the message names the range: {e}");
        }
        let e = load_with("blur_sigma_px = 1.0", "blur_sigma_px = 1e5")
            .unwrap_err()
            .to_string();
        assert!(e.contains("0..=20 px"), "{e}");
        load_with("blur_sigma_px = 1.0", "blur_sigma_px = 20.0").unwrap();
    }

    #[test]
    fn centre_maps_to_pose_and_round_trips() {
        let m = model();
        let pose = CameraPose {
            centre_mm: [10.0, 20.0],
            rotation_rad: 1e-4,
        };
        let c = m.board_to_pixel(&pose, [10.0, 20.0]);
        assert!((c[0] - 639.5).abs() < 1e-12 && (c[1] - 511.5).abs() < 1e-12);
        for p in [[0.0, 0.0], [1279.0, 1023.0], [100.0, 900.0]] {
            let b = m.pixel_to_board(&pose, p);
            let q = m.board_to_pixel(&pose, b);
            assert!(
                (p[0] - q[0]).abs() < 1e-9 && (p[1] - q[1]).abs() < 1e-9,
                "{p:?} {q:?}"
            );
        }
        // A board point 1 mm towards +y appears above the centre (smaller image y).
        let up = m.board_to_pixel(
            &CameraPose {
                centre_mm: [0.0, 0.0],
                rotation_rad: -m.rotation_deg.to_radians(),
            },
            [0.0, 1.0],
        );
        assert!((up[1] - (511.5 - 250.0)).abs() < 0.5, "{up:?}");
    }

    #[test]
    fn corner_distortion_is_as_configured() {
        let m = model();
        let pose = CameraPose::default();
        // Undistorted corner direction: map a board point, compare to the linear model.
        let mut no_dist = m.clone();
        no_dist.distortion_px_at_corner = 0.0;
        let b = no_dist.pixel_to_board(&pose, [0.0, 0.0]);
        let p = m.board_to_pixel(&pose, b);
        let shift = ((p[0] - 0.0).powi(2) + (p[1] - 0.0).powi(2)).sqrt();
        assert!((shift - 1.6).abs() < 1e-9, "{shift}");
    }
}
