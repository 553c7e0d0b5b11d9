//! [`Camera`]: an orbit camera around the centre of the volume's box.
//!
//! Model space is physical millimetres with the box centred on the origin and the
//! volume's index axes along x, y, z (patient LPS for medical data: x to the
//! patient's left, y to posterior, z to superior). The camera orbits the origin
//! with z up: azimuth 0 looks from anterior (−y) at the face, 90° from the
//! patient's left (+x); elevation lifts it towards superior. Distance is in
//! multiples of the box's bounding-sphere radius, so one camera frames every
//! dataset alike.

use glam::{Mat4, Quat, Vec3};

use crate::settings::Choice;

/// How the camera projects.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Projection {
    /// Rays fan out from the eye.
    #[default]
    Perspective,
    /// Parallel rays; the view is as tall as the perspective view's at the
    /// volume's centre, so switching keeps the framing.
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
                "parallel rays, as tall as the perspective view at the volume's centre"
            }
        }
    }
}

crate::choice_setting!(Projection);

crate::settings! {
    /// An orbit camera around the volume's centre.
    #[derive(Debug, Clone, Copy, PartialEq)]
    pub struct Camera in Camera {
        /// Camera azimuth in degrees about the vertical axis: 0 looks at the
        /// face (from anterior), 90 from the patient's left.
        pub azimuth_deg: f32 = 0.0, "az" | "azimuth", degrees(-3600.0, 3600.0);
        /// Camera elevation in degrees above the horizontal.
        pub elevation_deg: f32 = 0.0, "el" | "elevation", degrees(-90.0, 90.0);
        /// Camera distance from the volume's centre, in radii of its bounding
        /// sphere (below 1 the camera is inside the volume).
        pub distance: f32 = 3.0, "dist" | "distance",
            number(0.05, 100.0, "a number of bounding-sphere radii", "radii");
        /// Vertical field of view in degrees; orthographic views are as tall
        /// as perspective ones at the volume's centre.
        pub fov_y_deg: f32 = 30.0, "fov", degrees(1.0, 120.0);
        /// Camera roll in degrees: the image turns counter-clockwise about the
        /// line of sight.
        pub roll_deg: f32 = 0.0, "roll", degrees(-360.0, 360.0);
        /// Camera projection.
        pub projection: Projection = Projection::Perspective, "proj" | "projection", by_type();
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
            eye: toward_eye * self.distance * radius,
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
        let far = (self.distance + 1.0) * radius * 1.01;
        // WebGPU clip space: depth 0..1 and y up, the Direct3D convention.
        let proj = match self.projection {
            Projection::Perspective => {
                // Near and far enclose the bounding sphere; near stays positive inside it.
                let near = ((self.distance - 1.0) * radius * 0.5).max(radius * 0.01);
                glam::camera::rh::proj::directx::perspective(
                    self.fov_y_deg.to_radians(),
                    aspect,
                    near,
                    far,
                )
            }
            Projection::Orthographic => {
                // Rays may start behind the eye: the whole sphere is in view.
                let near = (self.distance - 1.01) * radius;
                let half_h = self.distance * radius * (self.fov_y_deg.to_radians() * 0.5).tan();
                let half_w = half_h * aspect;
                glam::camera::rh::proj::directx::orthographic(
                    -half_w, half_w, -half_h, half_h, near, far,
                )
            }
        };
        proj * view
    }
}

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
