//! The viewer's camera: an orbit around a target (drag to turn, pan, zoom) that can also fly
//! (WASD + QE move eye and target together), or sit exactly on a capture camera.
//!
//! Angles follow [`splat::Camera::orbit`]: `yaw` turns about the vertical axis, `pitch` lifts
//! the eye above the horizon, and up is −y (captures use OpenCV frames with +y down). The
//! headless `metasplat render` orbit is built from the same [`ViewCamera::framing`], so the
//! first frame a user sees in the window is the first frame of that orbit.

use glam::Vec3;
use splat::Camera;

/// Closest the eye gets to the target, as a fraction of the framing distance: zooming slows
/// down towards the target and never crosses it.
const MIN_DISTANCE_FRACTION: f32 = 1e-3;
/// Pitch stops short of straight up or down, where yaw loses its meaning.
const MAX_PITCH: f32 = 1.55;
/// The framing keeps the splats' bounding sphere a little inside the view.
const FRAMING_MARGIN: f32 = 1.2;
/// How far above the horizon the framing and the orbit look from.
pub const FRAMING_PITCH: f32 = 0.3;

#[derive(Clone, Debug, PartialEq)]
pub struct ViewCamera {
    pub target: Vec3,
    pub distance: f32,
    pub yaw: f32,
    pub pitch: f32,
    /// Field of view across the shorter side of the image, radians (vertical in a landscape
    /// window), so a framing holds at any aspect ratio.
    pub fov_y: f32,
    /// Distance scale of the scene (its framing distance): panning, flying and the zoom limit
    /// are relative to it, so the controls feel the same at any scene size.
    pub scale: f32,
    /// When set, the view is exactly this capture camera (focal lengths, principal point and
    /// pose), resized to the window; any movement leaves it for the orbit it approximates.
    pub exact: Option<Camera>,
}

impl ViewCamera {
    /// The view that frames the splats: the bounds of most of their means
    /// ([`splat::camera::scene_bounds`]) fill the view, from a little above. `None` when no
    /// mean is finite.
    pub fn framing(means: &[Vec3], fov_y: f32) -> Option<Self> {
        let (center, radius) = splat::camera::scene_bounds(means)?;
        let distance = FRAMING_MARGIN * radius / (0.5 * fov_y).sin();
        Some(Self {
            target: center,
            distance,
            yaw: 0.0,
            pitch: FRAMING_PITCH,
            fov_y,
            scale: distance,
            exact: None,
        })
    }

    /// The orbit view from `eye` towards `target`.
    pub fn looking(eye: Vec3, target: Vec3, fov_y: f32) -> Self {
        let offset = eye - target;
        let distance = offset.length().max(f32::MIN_POSITIVE);
        let dir = offset / distance;
        Self {
            target,
            distance,
            yaw: dir.x.atan2(-dir.z),
            pitch: (-dir.y)
                .clamp(-1.0, 1.0)
                .asin()
                .clamp(-MAX_PITCH, MAX_PITCH),
            fov_y,
            scale: distance,
            exact: None,
        }
    }

    /// Exactly a capture camera; its orbit target lies `distance` ahead of it.
    pub fn at_capture(cam: &Camera, distance: f32) -> Self {
        let eye = cam.position();
        let forward = cam.rotation.transpose() * Vec3::Z;
        let fov_y = 2.0 * (0.5 * cam.height as f32 / cam.fy).atan();
        let mut view = Self::looking(eye, eye + forward * distance, fov_y);
        view.scale = distance;
        view.exact = Some(cam.clone());
        view
    }

    pub fn eye(&self) -> Vec3 {
        self.target + self.offset_direction() * self.distance
    }

    /// Unit vector from the target to the eye.
    fn offset_direction(&self) -> Vec3 {
        Vec3::new(
            self.pitch.cos() * self.yaw.sin(),
            -self.pitch.sin(),
            -self.pitch.cos() * self.yaw.cos(),
        )
    }

    /// Unit view direction (eye towards target).
    pub fn forward(&self) -> Vec3 {
        -self.offset_direction()
    }

    /// The renderer's camera for a `width`×`height` view.
    pub fn camera(&self, width: u32, height: u32) -> Camera {
        if let Some(c) = &self.exact {
            return c.resized(width, height);
        }
        // In a portrait view the field of view is the horizontal one: widen the vertical one.
        let fov = if width < height {
            2.0 * ((0.5 * self.fov_y).tan() * height as f32 / width as f32).atan()
        } else {
            self.fov_y
        };
        Camera::orbit(
            self.target,
            self.distance,
            self.yaw,
            self.pitch,
            fov,
            width,
            height,
        )
    }

    /// Turns the eye around the target by `dyaw`, `dpitch` radians.
    pub fn orbit(&mut self, dyaw: f32, dpitch: f32) {
        self.leave_capture();
        self.yaw = (self.yaw + dyaw).rem_euclid(std::f32::consts::TAU);
        self.pitch = (self.pitch + dpitch).clamp(-MAX_PITCH, MAX_PITCH);
    }

    /// Moves eye and target sideways: `dx`, `dy` in fractions of the view height at the target.
    pub fn pan(&mut self, dx: f32, dy: f32) {
        self.leave_capture();
        let (right, down) = self.screen_axes();
        let span = 2.0 * self.distance * (0.5 * self.fov_y).tan();
        self.target += (right * dx + down * dy) * span;
    }

    /// Zooms by `steps` (positive: closer). The distance shrinks geometrically and stops at a
    /// small fraction of the scene scale, so the eye never reaches or crosses the target.
    pub fn zoom(&mut self, steps: f32) {
        self.leave_capture();
        let min = MIN_DISTANCE_FRACTION * self.scale;
        self.distance = (self.distance * (-0.1 * steps).exp()).max(min);
    }

    /// Flies: `forward` along the view direction, `right` sideways and `up` along the world's
    /// up (−y), each in units of the scene scale. Eye and target move together.
    pub fn fly(&mut self, forward: f32, right: f32, up: f32) {
        self.leave_capture();
        let (r, _) = self.screen_axes();
        let delta = (self.forward() * forward + r * right + Vec3::NEG_Y * up) * self.scale;
        self.target += delta;
    }

    /// Camera +x and +y (right and down on screen) in world space.
    fn screen_axes(&self) -> (Vec3, Vec3) {
        let f = self.forward();
        let right = f.cross(Vec3::NEG_Y).normalize_or_zero();
        (right, f.cross(right))
    }

    fn leave_capture(&mut self) {
        self.exact = None;
    }
}

/// Index of the camera whose centre is nearest to `eye`.
pub fn nearest_camera(cameras: &[Camera], eye: Vec3) -> Option<usize> {
    cameras
        .iter()
        .enumerate()
        .min_by(|a, b| {
            let da = a.1.position().distance_squared(eye);
            let db = b.1.position().distance_squared(eye);
            da.total_cmp(&db)
        })
        .map(|(i, _)| i)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn view() -> ViewCamera {
        ViewCamera {
            target: Vec3::new(0.5, -1.0, 2.0),
            distance: 4.0,
            yaw: 0.7,
            pitch: 0.2,
            fov_y: 0.9,
            scale: 4.0,
            exact: None,
        }
    }

    #[test]
    fn orbit_keeps_the_target_and_the_distance() {
        let mut v = view();
        let target = v.target;
        for (dy, dp) in [(0.3, 0.1), (-2.0, 0.5), (5.0, -3.0), (0.01, 2.0)] {
            v.orbit(dy, dp);
            assert_eq!(v.target, target);
            assert!((v.eye().distance(target) - 4.0).abs() < 1e-4);
            // The camera the renderer gets looks at the target from that eye.
            let cam = v.camera(64, 48);
            assert!(cam.position().distance(v.eye()) < 1e-4);
            let p = cam.rotation * target + cam.translation;
            assert!(p.x.abs() < 1e-3 && p.y.abs() < 1e-3 && (p.z - 4.0).abs() < 1e-3);
        }
    }

    #[test]
    fn zoom_never_crosses_the_target() {
        let mut v = view();
        let before = v.eye() - v.target;
        for _ in 0..10_000 {
            v.zoom(50.0);
            assert!(v.distance > 0.0);
            let now = v.eye() - v.target;
            assert!(now.dot(before) > 0.0, "the eye passed the target");
        }
        assert!(v.distance >= MIN_DISTANCE_FRACTION * v.scale * 0.999);
        v.zoom(-10.0);
        assert!(v.distance > MIN_DISTANCE_FRACTION * v.scale);
    }

    #[test]
    fn fly_moves_along_the_view_direction() {
        let mut v = view();
        let (eye, forward) = (v.eye(), v.forward());
        v.fly(0.25, 0.0, 0.0);
        let moved = v.eye() - eye;
        assert!((moved.length() - 0.25 * v.scale).abs() < 1e-4);
        assert!(moved.normalize().dot(forward) > 0.9999);
        // Strafing and rising are perpendicular to the view direction.
        let eye = v.eye();
        v.fly(0.0, 0.5, 0.0);
        assert!((v.eye() - eye).dot(forward).abs() < 1e-4);
        let eye = v.eye();
        v.fly(0.0, 0.0, 0.5);
        assert!((v.eye() - eye).normalize().dot(Vec3::NEG_Y) > 0.9999);
    }

    #[test]
    fn pan_keeps_the_view_direction() {
        let mut v = view();
        let forward = v.forward();
        v.pan(0.3, -0.2);
        assert!(v.forward().dot(forward) > 0.99999);
        assert!(v.target != view().target);
    }

    #[test]
    fn framing_puts_every_mean_in_view() {
        // A skewed cloud away from the origin.
        let mut means = Vec::new();
        let mut s = 12345u64;
        let mut next = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 40) as f32 / (1u64 << 24) as f32 - 0.5
        };
        for _ in 0..2000 {
            means.push(Vec3::new(
                3.0 + 4.0 * next(),
                -2.0 + 1.0 * next(),
                10.0 + 2.0 * next(),
            ));
        }
        let v = ViewCamera::framing(&means, 50f32.to_radians()).unwrap();
        for (w, h) in [(640, 480), (480, 640), (100, 100)] {
            let cam = v.camera(w, h);
            for m in &means {
                let p = cam.rotation * *m + cam.translation;
                assert!(p.z > 0.0, "a mean behind the camera");
                let (u, vv) = (cam.fx * p.x / p.z + cam.cx, cam.fy * p.y / p.z + cam.cy);
                assert!(
                    (0.0..w as f32).contains(&u) && (0.0..h as f32).contains(&vv),
                    "mean {m} projects to ({u}, {vv}) outside {w}x{h}"
                );
            }
        }
        assert!(ViewCamera::framing(&[Vec3::NAN], 1.0).is_none());
    }

    #[test]
    fn a_capture_camera_is_shown_exactly_until_the_user_moves() {
        let cam = Camera::look_at(
            Vec3::new(1.0, -2.0, -3.0),
            Vec3::new(0.2, 0.1, 0.0),
            Vec3::NEG_Y,
            300.0,
            310.0,
            200,
            150,
        );
        let mut v = ViewCamera::at_capture(&cam, 2.0);
        assert_eq!(v.camera(200, 150), cam);
        // The orbit it leaves for has the same eye and view direction.
        v.orbit(0.0, 0.0);
        assert!(v.exact.is_none());
        let orbit = v.camera(200, 150);
        assert!(orbit.position().distance(cam.position()) < 1e-4);
        let f = |c: &Camera| c.rotation.transpose() * Vec3::Z;
        assert!(f(&orbit).dot(f(&cam)) > 0.9999);
    }

    #[test]
    fn snapping_picks_the_nearest_camera() {
        let cams: Vec<Camera> = [-3.0f32, 0.5, 4.0, 9.0]
            .iter()
            .map(|&x| {
                Camera::look_at(
                    Vec3::new(x, 0.0, -5.0),
                    Vec3::new(x, 0.0, 0.0),
                    Vec3::NEG_Y,
                    100.0,
                    100.0,
                    64,
                    48,
                )
            })
            .collect();
        assert_eq!(nearest_camera(&cams, Vec3::new(0.0, 1.0, -5.0)), Some(1));
        assert_eq!(nearest_camera(&cams, Vec3::new(7.0, 0.0, -4.0)), Some(3));
        assert_eq!(nearest_camera(&cams, Vec3::new(-9.0, 0.0, 0.0)), Some(0));
        assert_eq!(nearest_camera(&[], Vec3::ZERO), None);
    }
}
