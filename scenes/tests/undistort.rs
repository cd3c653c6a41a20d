//! Undistortion at load against an analytic reference: a photo made by distorting a known
//! pinhole image comes back as that image, its borderless rays are named, and, for a metalens,
//! undistorting the blurred photo and blurring the pinhole image agree to well within what the
//! blur itself changes (the order the loader takes).

use glam::{DMat3, DVec3, Vec3};
use scenes::undistort::Remap;
use scenes::{Camera, CameraModel, Distortion, Photo, Rigid};

const W: u32 = 120;
const H: u32 = 90;

fn camera() -> Camera {
    Camera {
        name: "a".into(),
        width: W,
        height: H,
        fx: 100.0,
        fy: 100.0,
        cx: 60.0,
        cy: 45.0,
        world_to_camera: Rigid {
            rotation: DMat3::IDENTITY,
            translation: DVec3::ZERO,
        },
        distortion: None,
    }
}

fn lens() -> Distortion {
    Distortion {
        model: CameraModel::OpenCv,
        k1: 0.08,
        k2: -0.02,
        p1: 0.002,
        p2: -0.001,
        rational: [0.0; 4],
    }
}

/// The scene seen along the normalised ray `(x, y)`: smooth, so bilinear sampling of it is
/// nearly exact.
fn scene(x: f64, y: f64) -> [f32; 3] {
    [
        (0.5 + 0.4 * (7.0 * x).sin() * (5.0 * y).cos()) as f32,
        (0.5 + 0.4 * (4.0 * x + 3.0 * y).sin()) as f32,
        (0.5 + 0.4 * (6.0 * y).sin()) as f32,
    ]
}

/// The ray a distorted normalised point came from, by fixed-point iteration in f64.
fn undistort_point(d: &Distortion, xd: f64, yd: f64) -> (f64, f64) {
    let (mut x, mut y) = (xd, yd);
    for _ in 0..100 {
        let (dx, dy) = d.distort(x, y);
        x -= dx - xd;
        y -= dy - yd;
    }
    (x, y)
}

/// A photo whose pixel centres sample `f` at their normalised coordinates, optionally seen
/// through the lens (the ray each distorted pixel shows).
fn photo(through: Option<&Distortion>, f: &dyn Fn(f64, f64) -> [f32; 3]) -> Photo {
    let c = camera();
    let mut data = Vec::new();
    for y in 0..H {
        for x in 0..W {
            let (u, v) = (
                (x as f64 + 0.5 - c.cx) / c.fx,
                (y as f64 + 0.5 - c.cy) / c.fy,
            );
            let (u, v) = through.map_or((u, v), |d| undistort_point(d, u, v));
            data.extend(f(u, v));
        }
    }
    Photo {
        width: W,
        height: H,
        data,
    }
}

fn mean_abs(a: &Photo, b: &Photo, keep: &[bool]) -> f64 {
    let (mut sum, mut n) = (0.0, 0usize);
    for (i, k) in keep.iter().enumerate() {
        if *k {
            for c in 0..3 {
                sum += (a.data[3 * i + c] - b.data[3 * i + c]).abs() as f64;
            }
            n += 3;
        }
    }
    sum / n as f64
}

/// FULL_OPENCV's rational lens, as COLMAP's text model writes it.
fn full_lens() -> Distortion {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cameras.txt");
    std::fs::write(
        &path,
        "# c\n1 FULL_OPENCV 120 90 100 100 60 45 0.08 -0.02 0.002 -0.001 0.03 0.05 -0.01 0.004\n",
    )
    .unwrap();
    let cameras = scenes::colmap::text::read_cameras(&path).unwrap();
    let d = cameras[0].intrinsics().distortion.unwrap();
    assert_eq!(d.model, CameraModel::FullOpenCv);
    assert_eq!(d.rational, [0.03, 0.05, -0.01, 0.004]);
    d
}

#[test]
fn a_distorted_photo_comes_back_as_the_pinhole_image() {
    for d in [lens(), full_lens()] {
        comes_back(d);
    }
}

fn comes_back(d: Distortion) {
    let remap = Remap::new(&camera(), &d);
    let (truth, taken) = (photo(None, &scene), photo(Some(&d), &scene));
    let back = remap.apply(&taken);
    let all = vec![true; (W * H) as usize];
    let (before, after) = (
        mean_abs(&taken, &truth, &all),
        mean_abs(&back, &truth, &remap.valid),
    );
    eprintln!("mean error to the pinhole image: as taken {before:.5}, undistorted {after:.5}");
    assert!(after < 0.05 * before, "{after} vs {before}");
    // The rays the photo does not hold are the ones the lens sends beyond its border, and a
    // mask leaves exactly them out.
    assert!(remap.invalid_count() > 0 && remap.invalid_count() < (W * H / 10) as usize);
    let c = camera();
    for (i, ok) in remap.valid.iter().enumerate() {
        let (x, y) = ((i as u32 % W) as f64 + 0.5, (i as u32 / W) as f64 + 0.5);
        let (xd, yd) = d.distort((x - c.cx) / c.fx, (y - c.cy) / c.fy);
        let (u, v) = (xd * c.fx + c.cx, yd * c.fy + c.cy);
        assert_eq!(
            *ok,
            (0.0..=W as f64).contains(&u) && (0.0..=H as f64).contains(&v)
        );
    }
    let mask = remap.apply_mask(None);
    assert!(
        mask.iter()
            .zip(&remap.valid)
            .all(|(m, v)| (*m == 1.0) == *v)
    );
}

#[test]
fn for_a_metalens_undistorting_then_blurring_is_what_the_lens_does() {
    use aberration::optics::{SimConfig, simulate_grid};
    let (psf, _) = simulate_grid(&SimConfig::small(9), &|_, _| {}).unwrap();
    let plan = aberration::BlurPlan::new(&psf, W as usize, H as usize, aberration::BlurMode::Tiled)
        .unwrap();
    let blur = |p: &Photo| {
        let px: Vec<Vec3> = p
            .data
            .chunks_exact(3)
            .map(|c| Vec3::new(c[0], c[1], c[2]))
            .collect();
        let out = plan.apply_pixels(&px).unwrap();
        Photo {
            width: W,
            height: H,
            data: out.iter().flat_map(|v| v.to_array()).collect(),
        }
    };
    // A sharper scene, so the blur has something to change.
    let sharp = |x: f64, y: f64| {
        let v = if ((12.0 * x).floor() + (12.0 * y).floor()) as i64 % 2 == 0 {
            0.9
        } else {
            0.1
        };
        [v as f32, (1.0 - v) as f32, 0.5]
    };
    let d = lens();
    let remap = Remap::new(&camera(), &d);
    let truth = photo(None, &sharp);
    // The lens: the scene distorted onto the sensor, blurred there.
    let recorded = blur(&photo(Some(&d), &sharp));
    // The loader undistorts it; training compares with the pinhole render blurred.
    let model_error = mean_abs(&remap.apply(&recorded), &blur(&truth), &remap.valid);
    let blur_effect = mean_abs(&blur(&truth), &truth, &remap.valid);
    let resampling = mean_abs(&remap.apply(&photo(Some(&d), &sharp)), &truth, &remap.valid);
    eprintln!(
        "undistort(blur(distorted)) vs blur(pinhole): {model_error:.5}; the blur changes {blur_effect:.5}; resampling alone {resampling:.5}"
    );
    assert!(
        model_error < 0.25 * blur_effect,
        "{model_error} vs {blur_effect}"
    );
    assert!(model_error < resampling, "{model_error} vs {resampling}");
}
