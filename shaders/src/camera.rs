//! [`Camera`]: an orbit camera around a target point.
//!
//! Model space is physical millimetres with the box centred on the origin and the
//! volume's index axes along x, y, z (patient LPS for medical data: x to the
//! patient's left, y to posterior, z to superior). The camera orbits its target
//! (the origin by default) with z up: azimuth 0 looks from anterior (−y) at the
//! face, 90° from the patient's left (+x); elevation lifts it towards superior.
//! Distance is in multiples of the box's bounding-sphere radius, so one camera
//! frames every dataset alike. [`Camera::fitted`] frames a box (what the
//! transfer function shows) to [`FIT_SHARE`] of the image's smaller side.

use glam::{Mat4, Quat, Vec3};

use crate::settings::Choice;

/// How the camera projects.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Projection {
    /// Rays fan out from the eye.
    #[default]
    Perspective,
    /// Parallel rays; the view is as tall as the perspective view's at the
    /// target, so switching keeps the framing.
    Orthographic,
}

impl Choice for Projection {
    const ALL: &'static [Projection] = &[Projection::Perspective, Projection::Orthographic];

    fn name(self) -> &'static str {
        match self {
            Projection::Perspective => "perspective",
            Projection::Orthographic => "orthographic",
        }
    }

    fn doc(self) -> &'static str {
        match self {
            Projection::Perspective => "rays fan out from the eye",
            Projection::Orthographic => {
                "parallel rays, as tall as the perspective view at the target"
            }
        }
    }
}

crate::choice_setting!(Projection);

/// The share of the image's smaller side a fitted camera gives the box it frames.
pub const FIT_SHARE: f32 = 0.85;
/// The share of the shown blocks a fit may leave out on each side of each
/// axis when an empty layer of blocks cuts them off from the rest, so that a
/// speck of noise far from the rest does not shrink the view.
pub const FIT_STRAY: f64 = 0.01;

crate::settings! {
    /// An orbit camera around a target point.
    #[derive(Debug, Clone, Copy, PartialEq)]
    pub struct Camera in Camera {
        /// Camera azimuth in degrees about the vertical axis: 0 looks at the
        /// face (from anterior), 90 from the patient's left.
        pub azimuth_deg: f32 = 0.0, "az" | "azimuth", degrees(-3600.0, 3600.0);
        /// Camera elevation in degrees above the horizontal.
        pub elevation_deg: f32 = 0.0, "el" | "elevation", degrees(-90.0, 90.0);
        /// Camera distance from its target, in radii of the volume's bounding
        /// sphere.
        pub distance: f32 = 3.0, "dist" | "distance",
            number(MIN_DISTANCE, MAX_DISTANCE, "a number of bounding-sphere radii", "radii");
        /// Vertical field of view in degrees; orthographic views are as tall
        /// as perspective ones at the target.
        pub fov_y_deg: f32 = 30.0, "fov", degrees(1.0, 120.0);
        /// Camera roll in degrees: the image turns counter-clockwise about the
        /// line of sight.
        pub roll_deg: f32 = 0.0, "roll", degrees(-360.0, 360.0);
        /// Camera projection.
        pub projection: Projection = Projection::Perspective, "proj" | "projection", by_type();
        /// The point the camera orbits and looks at: millimetres to the
        /// patient's left (the volume's x axis) of the volume's centre.
        pub target_x: f32 = 0.0, "tx" | "target-x", number(-1e4, 1e4, "millimetres from the volume's centre", "mm");
        /// The point the camera orbits: millimetres posterior (y) of the volume's centre.
        pub target_y: f32 = 0.0, "ty" | "target-y", number(-1e4, 1e4, "millimetres from the volume's centre", "mm");
        /// The point the camera orbits: millimetres superior (z) of the volume's centre.
        pub target_z: f32 = 0.0, "tz" | "target-z", number(-1e4, 1e4, "millimetres from the volume's centre", "mm");
        /// Frame what the transfer function shows: the target moves to the
        /// centre of its non-empty blocks (stray specks apart from the rest,
        /// up to 1 % of them per side, left out) and the distance makes them fill 85 % of the image's smaller
        /// side from this direction (a view session does it once and answers
        /// with the camera it chose).
        pub fit: bool = false, "fit", by_type();
    }
}

/// The camera's frame in model space.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraBasis {
    /// The eye position.
    pub eye: Vec3,
    /// Unit vector from the eye into the scene.
    pub forward: Vec3,
    /// Unit vector to the image's right.
    pub right: Vec3,
    /// Unit vector to the image's top.
    pub up: Vec3,
}

impl Camera {
    /// The point the camera orbits, model mm.
    pub fn target(&self) -> Vec3 {
        Vec3::new(self.target_x, self.target_y, self.target_z)
    }

    /// The eye and its axes for a box with bounding-sphere radius `radius` (mm).
    pub fn basis(&self, radius: f32) -> CameraBasis {
        let (sin_az, cos_az) = self.azimuth_deg.to_radians().sin_cos();
        let (sin_el, cos_el) = self.elevation_deg.to_radians().sin_cos();
        // From the centre towards the eye.
        let toward_eye = Vec3::new(sin_az * cos_el, -cos_az * cos_el, sin_el);
        // Right stays horizontal, so the basis is defined even looking straight down.
        let level_right = Vec3::new(cos_az, sin_az, 0.0);
        let level_up = toward_eye.cross(level_right);
        // Roll turns the image counter-clockwise: the camera's axes turn the
        // other way about the line of sight.
        let roll = Quat::from_axis_angle(toward_eye, -self.roll_deg.to_radians());
        let (right, up) = (roll * level_right, roll * level_up);
        CameraBasis {
            eye: self.target() + toward_eye * self.distance * radius,
            forward: -toward_eye,
            right,
            up,
        }
    }

    /// View-projection matrix (model → clip, depth 0..1) for a box with
    /// bounding-sphere radius `radius` and an image of the given aspect (w / h).
    pub fn view_proj(&self, radius: f32, aspect: f32) -> Mat4 {
        let b = self.basis(radius);
        let view = glam::camera::rh::view::look_to_mat4(b.eye, b.forward, b.up);
        // Near and far enclose the volume's bounding sphere, measured along
        // the view from the eye.
        let centre_depth = -b.eye.dot(b.forward);
        let far = (centre_depth + radius) * 1.01;
        // WebGPU clip space: depth 0..1 and y up, the Direct3D convention.
        let proj = match self.projection {
            Projection::Perspective => {
                // Near stays positive inside the sphere.
                let near = ((centre_depth - radius) * 0.5).max(radius * 0.01);
                glam::camera::rh::proj::directx::perspective(
                    self.fov_y_deg.to_radians(),
                    aspect,
                    near,
                    far,
                )
            }
            Projection::Orthographic => {
                // Rays may start behind the eye: the whole sphere is in view.
                let near = centre_depth - 1.01 * radius;
                let half_h = self.distance * radius * (self.fov_y_deg.to_radians() * 0.5).tan();
                let half_w = half_h * aspect;
                glam::camera::rh::proj::directx::orthographic(
                    -half_w, half_w, -half_h, half_h, near, far,
                )
            }
        };
        proj * view
    }

    /// This camera turned to frame the box `min`..`max` (model mm) of a
    /// volume with bounding-sphere radius `radius`, in an image of aspect
    /// `aspect` (w / h): the target at the box's centre and the distance at
    /// which, seen from this camera's direction, every corner lies within
    /// [`FIT_SHARE`] of the image's smaller side (centred on the target).
    /// Angles, field of view and projection stay; `fit` is cleared.
    pub fn fitted(&self, min: Vec3, max: Vec3, radius: f32, aspect: f32) -> Camera {
        let target = (min + max) * 0.5;
        let b = Camera {
            target_x: 0.0,
            target_y: 0.0,
            target_z: 0.0,
            ..*self
        }
        .basis(radius);
        // A corner `lateral` mm off the line of sight at depth `d` lies
        // lateral / (d · tan(fov/2)) half-heights from the image's centre;
        // it must lie within FIT_SHARE of the smaller side's half.
        let reach = FIT_SHARE * aspect.min(1.0) * (self.fov_y_deg.to_radians() * 0.5).tan();
        let mut eye_distance = 0.0f32;
        for corner in box_corners(min, max) {
            let c = corner - target;
            let lateral = c.dot(b.right).abs().max(c.dot(b.up).abs());
            let needed = match self.projection {
                Projection::Perspective => lateral / reach - c.dot(b.forward),
                // Orthographic views are as tall as perspective ones at the target.
                Projection::Orthographic => lateral / reach,
            };
            eye_distance = eye_distance.max(needed);
        }
        // Rounded as clients round what they send back (0.01 mm, 0.001 radii),
        // so a client adopting the camera sends no change.
        let round = |v: f32, per_unit: f32| (v * per_unit).round() / per_unit;
        Camera {
            target_x: round(target.x, 100.0),
            target_y: round(target.y, 100.0),
            target_z: round(target.z, 100.0),
            distance: round(eye_distance / radius.max(f32::MIN_POSITIVE), 1000.0)
                .clamp(MIN_DISTANCE as f32, MAX_DISTANCE as f32),
            fit: false,
            ..*self
        }
    }
}

/// The 8 corners of the axis-aligned box `min`..`max`.
pub fn box_corners(min: Vec3, max: Vec3) -> [Vec3; 8] {
    std::array::from_fn(|corner| {
        Vec3::select(
            glam::BVec3::new(corner & 1 != 0, corner & 2 != 0, corner & 4 != 0),
            max,
            min,
        )
    })
}

/// The `dist` setting's range, in bounding-sphere radii.
const MIN_DISTANCE: f64 = 0.05;
/// The `dist` setting's range, in bounding-sphere radii.
const MAX_DISTANCE: f64 = 100.0;

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: Vec3, b: Vec3) -> bool {
        (a - b).length() < 1e-5
    }

    #[test]
    fn front_view_looks_from_anterior_with_patient_left_on_the_right() {
        let b = Camera::default().basis(1.0);
        assert!(close(b.forward, Vec3::Y));
        assert!(close(b.right, Vec3::X));
        assert!(close(b.up, Vec3::Z));
        assert!(close(b.eye, Vec3::new(0.0, -3.0, 0.0)));
    }

    #[test]
    fn looking_straight_down_keeps_a_basis() {
        let cam = Camera {
            elevation_deg: 90.0,
            ..Camera::default()
        };
        let b = cam.basis(1.0);
        assert!(close(b.forward, -Vec3::Z));
        assert!((b.up.length() - 1.0).abs() < 1e-5);
        assert!(b.right.dot(b.up).abs() < 1e-5);
    }

    #[test]
    fn the_box_centre_projects_to_the_image_centre() {
        let cam = Camera {
            azimuth_deg: 37.0,
            elevation_deg: -20.0,
            ..Camera::default()
        };
        let clip = cam.view_proj(150.0, 1.5) * glam::Vec4::new(0.0, 0.0, 0.0, 1.0);
        let ndc = clip.truncate() / clip.w;
        assert!(ndc.x.abs() < 1e-5 && ndc.y.abs() < 1e-5);
        assert!(ndc.z > 0.0 && ndc.z < 1.0);
    }

    #[test]
    fn orthographic_rays_are_parallel_and_frame_like_perspective() {
        let cam = Camera {
            projection: Projection::Orthographic,
            ..Camera::default()
        };
        let inv = cam.view_proj(1.0, 1.0).inverse();
        let ray = |x: f32, y: f32| {
            let near = inv.project_point3(Vec3::new(x, y, 0.0));
            let far = inv.project_point3(Vec3::new(x, y, 1.0));
            (near, (far - near).normalize())
        };
        let (a, da) = ray(-0.9, 0.3);
        let (b, db) = ray(0.5, -0.7);
        assert!((da - db).length() < 1e-5, "parallel");
        assert!((da - Vec3::Y).length() < 1e-5, "along the view");
        assert!((a - b).length() > 0.1, "from different points");
        // The top of the view is as high as perspective's at the centre.
        let top = inv.project_point3(Vec3::new(0.0, 1.0, 0.5));
        assert!(
            (top.z - 3.0 * (15f32).to_radians().tan()).abs() < 1e-4,
            "{top}"
        );
        assert_eq!(
            Projection::named("orthographic"),
            Some(Projection::Orthographic)
        );
    }

    #[test]
    fn validation_names_the_field() {
        use crate::settings::Settings;
        let cam = Camera {
            elevation_deg: f32::NAN,
            ..Camera::default()
        };
        let e = cam.validate_fields().expect_err("NaN elevation");
        assert_eq!(e.setting, "el", "{e}");
        assert!(Camera::default().validate_fields().is_ok());
    }

    #[test]
    fn a_fitted_camera_frames_the_box_to_its_share_of_the_smaller_side() {
        let (min, max) = (Vec3::new(-30.0, -10.0, -50.0), Vec3::new(50.0, 40.0, 20.0));
        for projection in [Projection::Perspective, Projection::Orthographic] {
            for aspect in [1.5f32, 1.0, 0.6] {
                let cam = Camera {
                    azimuth_deg: 30.0,
                    elevation_deg: 20.0,
                    projection,
                    fit: true,
                    ..Camera::default()
                }
                .fitted(min, max, 100.0, aspect);
                assert!(!cam.fit);
                assert!(close(cam.target(), (min + max) * 0.5), "{cam:?}");
                let view_proj = cam.view_proj(100.0, aspect);
                let centre = view_proj.project_point3(cam.target());
                assert!(centre.x.abs() < 1e-4 && centre.y.abs() < 1e-4, "{centre}");
                // The farthest corner from the centre, in half-heights of the image.
                let mut reach = 0.0f32;
                for p in box_corners(min, max) {
                    let ndc = view_proj.project_point3(p);
                    assert!(ndc.z > 0.0 && ndc.z < 1.0, "{projection:?} {aspect}: {ndc}");
                    reach = reach.max((ndc.x * aspect).abs()).max(ndc.y.abs());
                }
                let share = reach / aspect.min(1.0);
                assert!(
                    (share - FIT_SHARE).abs() < 0.005,
                    "{projection:?} at aspect {aspect}: the box spans {share} of the smaller side"
                );
            }
        }
    }

    #[test]
    fn an_off_centre_target_keeps_the_whole_volume_between_near_and_far() {
        let cam = Camera {
            target_x: 80.0,
            target_z: -60.0,
            distance: 1.2,
            ..Camera::default()
        };
        let view_proj = cam.view_proj(100.0, 1.0);
        let b = cam.basis(100.0);
        // The bounding sphere's nearest and farthest points along the view.
        for sign in [-1.0f32, 1.0] {
            let p = b.forward * 100.0 * sign;
            let depth = view_proj.project_point3(p).z;
            assert!((0.0..=1.0).contains(&depth), "{sign}: {depth}");
        }
    }

    #[test]
    fn roll_turns_the_image_counter_clockwise() {
        let level = Camera::default().basis(1.0);
        let rolled = Camera {
            roll_deg: 90.0,
            ..Camera::default()
        }
        .basis(1.0);
        // The volume's top (z) now points to the image's left.
        assert!(close(rolled.forward, level.forward));
        assert!(close(rolled.right, -Vec3::Z), "{rolled:?}");
        assert!(close(rolled.up, Vec3::X), "{rolled:?}");
    }
}
