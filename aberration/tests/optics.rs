//! The PSF simulation against analytic optics (Airy pattern), conservation of energy,
//! mirror symmetry, and the independent reference figures of shared/notes/psf-reference.md.

use aberration::optics::phase::{Dispersion, meta_atom_duty, meta_atom_phase};
use aberration::optics::sensor::sample_psf;
use aberration::optics::{Lens, Propagator, SimConfig, simulate_grid};
use std::f64::consts::TAU;

#[test]
fn ideal_lens_focuses_to_an_airy_pattern() {
    // The paper's geometry (D = 0.5 mm, f = 1 mm) with an ideal hyperbolic lens at 452 nm.
    let lambda = 452.0;
    let lens = Lens::ideal(500.0, 1000.0, 0.35, lambda);
    let prop = Propagator::new(3000, lens.pitch_um);
    let transfer = prop.transfer(lambda, lens.focal_um);
    let win = prop.focal_window(&lens, lambda, 0.0, &transfer, 0.0, 20);
    let side = win.side();
    let row: Vec<f64> = (0..side)
        .map(|x| win.intensity[win.half * side + x])
        .collect();
    // The peak sits on the axis.
    let peak_at = (0..side)
        .max_by(|a, b| row[*a].total_cmp(&row[*b]))
        .unwrap();
    assert_eq!(peak_at, win.half, "focus is off axis");
    // First dark ring: first local minimum walking out from the centre.
    let first_min = (win.half + 1..side - 1)
        .find(|&x| row[x] <= row[x - 1] && row[x] <= row[x + 1])
        .expect("no dark ring in the window");
    let r_um = (first_min - win.half) as f64 * win.dx_um;
    let airy = 1.22 * lambda * 1e-3 * lens.focal_um / lens.aperture_um;
    assert!(
        (r_um - airy).abs() <= win.dx_um,
        "first dark ring at {r_um} um, Airy predicts {airy} um (one sample = {} um)",
        win.dx_um
    );
    // The ring is dark: far below the peak.
    assert!(row[first_min] < 0.02 * row[win.half]);
    // Energy: all incident power reaches the focal plane (nothing evanescent at NA 0.24).
    assert!(
        (win.total_power - 1.0).abs() < 1e-6,
        "focal power {}",
        win.total_power
    );
    // The core holds the Airy share of energy: 83.8% inside the first dark ring.
    let inside: f64 = (0..side)
        .flat_map(|y| (0..side).map(move |x| (y, x)))
        .filter(|&(y, x)| {
            let (dy, dx) = (y as f64 - win.half as f64, x as f64 - win.half as f64);
            dx.hypot(dy) * win.dx_um <= airy
        })
        .map(|(y, x)| win.intensity[y * side + x])
        .sum();
    assert!(
        (inside - 0.838).abs() < 0.03,
        "energy inside the first ring {inside}"
    );
}

#[test]
fn meta_atom_proxy_is_nearly_identity_at_its_design_wavelength() {
    // At 452 nm Tseng's fit maps the wrapped target phase u·2π back to about itself.
    for i in 0..10 {
        let u = i as f64 / 10.0;
        let phi = meta_atom_phase(452.0, meta_atom_duty(u));
        assert!((phi - u * TAU).abs() < 0.05 * TAU, "u={u}: phase {phi}");
    }
    // Longer wavelengths see less phase from the same pillar.
    let d = meta_atom_duty(0.5);
    assert!(meta_atom_phase(606.0, d) < meta_atom_phase(462.0, d));
    let l = Lens::default();
    assert_eq!(l.dispersion, Dispersion::MetaAtom);
}

fn small_config() -> SimConfig {
    SimConfig::small(31)
}

#[test]
fn grid_psfs_are_unit_sum_and_mirror_symmetric() {
    let cfg = small_config();
    let (grid, report) = simulate_grid(&cfg, &|_, _| {}).unwrap();
    assert_eq!((grid.grid(), grid.size()), (3, 31));
    // 3x3 grid: distinct radii 0, edge, corner.
    assert_eq!(report.angles_deg.len(), 3);
    assert!(
        (report.angles_deg[2] - 10.0).abs() < 1e-9,
        "corner at {}",
        report.angles_deg[2]
    );
    let k = grid.size();
    for gi in 0..9 {
        for c in 0..3 {
            let s: f64 = grid.kernel(gi, c).iter().map(|v| *v as f64).sum();
            assert!((s - 1.0).abs() < 1e-5, "PSF {gi}/{c} sums to {s}");
        }
    }
    for c in 0..3 {
        let peak = grid.kernel(4, c).iter().cloned().fold(0.0, f32::max);
        for i in 0..3 {
            // Left-right mirror: (i, 0) vs (i, 2); top-bottom: (0, i) vs (2, i).
            let (a, b) = (grid.kernel(i * 3, c), grid.kernel(i * 3 + 2, c));
            let (t, u) = (grid.kernel(i, c), grid.kernel(6 + i, c));
            for y in 0..k {
                for x in 0..k {
                    let lr = (a[y * k + x] - b[y * k + (k - 1 - x)]).abs();
                    let tb = (t[y * k + x] - u[(k - 1 - y) * k + x]).abs();
                    assert!(
                        lr <= 1e-5 * peak && tb <= 1e-5 * peak,
                        "asymmetry {lr} {tb} at {i},{y},{x}"
                    );
                }
            }
        }
    }
    // Off-axis PSFs differ from the on-axis one: the blur really varies over the field.
    let diff: f32 = grid
        .kernel(0, 1)
        .iter()
        .zip(grid.kernel(4, 1))
        .map(|(a, b)| (a - b).abs())
        .sum();
    assert!(
        diff > 0.05,
        "corner and centre PSFs are nearly equal ({diff})"
    );
}

#[test]
fn on_axis_neural_lens_matches_independent_reference() {
    // Figures from an independent float64 simulation (shared/notes/psf-reference.md).
    let cfg = SimConfig::default();
    let prop = Propagator::new(cfg.fft_size, cfg.lens.pitch_um);
    let crop_ref = [0.16, 0.22, 0.25];
    let peak_ref = [0.0028, 0.0227, 0.0103];
    for (ch, &lambda) in cfg.wavelengths_nm.iter().enumerate() {
        let transfer = prop.transfer(lambda, cfg.lens.focal_um);
        let win = prop.focal_window(&cfg.lens, lambda, 0.0, &transfer, 0.0, 150);
        let psf = sample_psf(&win, 0.0, cfg.psf_size, cfg.sensor_pitch_um, 0.0, 4);
        let crop: f64 = psf.iter().sum();
        let peak = psf.iter().cloned().fold(0.0, f64::max) / crop;
        eprintln!(
            "{lambda} nm: crop power {crop:.4} (ref {}), peak {peak:.5} (ref {})",
            crop_ref[ch], peak_ref[ch]
        );
        assert!(
            (crop - crop_ref[ch]).abs() < 0.015,
            "{lambda} nm: crop power {crop}"
        );
        assert!(
            (peak / peak_ref[ch] - 1.0).abs() < 0.15,
            "{lambda} nm: peak {peak}"
        );
    }
}

#[test]
fn bad_configurations_are_rejected() {
    let mut cfg = small_config();
    cfg.fft_size = 100; // 35 um grid cannot hold a 100 um aperture
    let err = simulate_grid(&cfg, &|_, _| {}).unwrap_err().to_string();
    assert!(err.contains("aperture"), "{err}");
    let mut cfg = small_config();
    cfg.max_field_deg = 95.0;
    assert!(simulate_grid(&cfg, &|_, _| {}).is_err());
}
