//! The initial splats: one isotropic Gaussian per point of the capture's cloud, as 3DGS
//! initialises from SfM points (scale = RMS distance to the 3 nearest neighbours, opacity
//! 0.1, colour from the point).

use glam::{DVec3, IVec3, Vec3};
use rayon::prelude::*;
use scenes::PointCloud;
use splat::Gaussians;
use splat::model::logit;
use std::collections::HashMap;

pub const INITIAL_OPACITY: f32 = 0.1;
/// Shells searched around a point before falling back to a linear scan.
const MAX_RING: i32 = 8;

/// Mean squared distance of each point to its `k` nearest other points. A uniform grid with
/// about two points per cell keeps this near-linear; kd-tree crates pulled in tens of
/// dependencies for this one start-up query.
pub fn mean_sq_knn(points: &[Vec3], k: usize) -> Vec<f32> {
    let n = points.len();
    if n < 2 {
        return vec![1e-4; n];
    }
    let (lo, hi) = points.iter().fold(
        (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
        |(lo, hi), p| (lo.min(*p), hi.max(*p)),
    );
    let span = (hi - lo).max(Vec3::splat(1e-6));
    let volume = span.x as f64 * span.y as f64 * span.z as f64;
    let cell = ((volume * 2.0 / n as f64).cbrt() as f32).max(span.max_element() / 1024.0);
    let key = |p: Vec3| ((p - lo) / cell).floor().as_ivec3();
    let mut grid: HashMap<IVec3, Vec<u32>> = HashMap::new();
    for (i, p) in points.iter().enumerate() {
        grid.entry(key(*p)).or_default().push(i as u32);
    }
    let max_ring = (span / cell).ceil().max_element() as i32 + 1;
    let k = k.min(n - 1);
    points
        .par_iter()
        .enumerate()
        .map(|(i, p)| {
            let c = key(*p);
            let mut best: Vec<f32> = Vec::with_capacity(k + 1);
            let push = |d: f32, best: &mut Vec<f32>| {
                if best.len() < k || d < best[k - 1] {
                    let at = best.partition_point(|b| *b <= d);
                    best.insert(at, d);
                    best.truncate(k);
                }
            };
            for ring in 0..=max_ring {
                if ring > MAX_RING {
                    // An isolated point: scanning ever larger shells costs more than all points.
                    best.clear();
                    for (j, q) in points.iter().enumerate() {
                        if j != i {
                            push(p.distance_squared(*q), &mut best);
                        }
                    }
                    break;
                }
                // Everything within `ring` cells is found; stop once the k-th best is closer
                // than any point of the next ring can be.
                for dz in -ring..=ring {
                    for dy in -ring..=ring {
                        for dx in -ring..=ring {
                            if dx.abs().max(dy.abs()).max(dz.abs()) != ring {
                                continue;
                            }
                            let Some(ids) = grid.get(&(c + IVec3::new(dx, dy, dz))) else {
                                continue;
                            };
                            for &j in ids {
                                if j as usize == i {
                                    continue;
                                }
                                push(p.distance_squared(points[j as usize]), &mut best);
                            }
                        }
                    }
                }
                let reach = ring as f32 * cell;
                if best.len() == k && best[k - 1] <= reach * reach {
                    break;
                }
            }
            best.iter().sum::<f32>() / best.len().max(1) as f32
        })
        .collect()
}

/// At most `budget` of the cloud's points, a seeded random subset in their original order
/// (the cloud itself when it fits): a run never starts above its splat budget, so the
/// budget bounds the model from the first step, not only its growth.
pub fn within_budget(
    cloud: &PointCloud,
    budget: usize,
    seed: u64,
) -> std::borrow::Cow<'_, PointCloud> {
    let n = cloud.len();
    if n <= budget {
        return std::borrow::Cow::Borrowed(cloud);
    }
    // Partial Fisher–Yates: the first `budget` slots end up a uniform sample.
    let mut index: Vec<usize> = (0..n).collect();
    let mut rng = base::SplitMix64::new(seed ^ 0xB0D6E7);
    for i in 0..budget {
        let j = i + (rng.next_u64() % (n - i) as u64) as usize;
        index.swap(i, j);
    }
    let mut keep = index[..budget].to_vec();
    keep.sort_unstable();
    std::borrow::Cow::Owned(PointCloud {
        positions: keep.iter().map(|&i| cloud.positions[i]).collect(),
        colors: keep.iter().map(|&i| cloud.colors[i]).collect(),
    })
}

/// Gaussians at the cloud's points, storing SH bands up to `sh_degree` (zero beyond DC).
pub fn from_points(cloud: &PointCloud, sh_degree: u32) -> Gaussians {
    let means: Vec<Vec3> = cloud
        .positions
        .iter()
        .map(|p: &DVec3| p.as_vec3())
        .collect();
    let d2 = mean_sq_knn(&means, 3);
    let mut g = Gaussians::new(sh_degree);
    let rest = vec![Vec3::ZERO; g.rest_count()];
    for (i, m) in means.iter().enumerate() {
        let c = Vec3::from_array(cloud.colors[i]);
        let log_s = 0.5 * d2[i].max(1e-7).ln();
        g.push(
            *m,
            Vec3::splat(log_s),
            [1.0, 0.0, 0.0, 0.0],
            logit(INITIAL_OPACITY),
            splat::sh::rgb_to_sh_dc(c),
            &rest,
        );
    }
    g
}

#[cfg(test)]
mod tests {
    use super::*;

    fn brute(points: &[Vec3], k: usize) -> Vec<f32> {
        points
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let mut d: Vec<f32> = points
                    .iter()
                    .enumerate()
                    .filter(|(j, _)| *j != i)
                    .map(|(_, q)| p.distance_squared(*q))
                    .collect();
                d.sort_by(f32::total_cmp);
                d[..k].iter().sum::<f32>() / k as f32
            })
            .collect()
    }

    #[test]
    fn grid_knn_matches_brute_force() {
        let mut rng = base::SplitMix64::new(4);
        // Clustered, flat and spread-out points: the grid must not miss far neighbours.
        let mut pts: Vec<Vec3> = (0..600)
            .map(|_| {
                Vec3::new(
                    rng.uniform(-5.0, 5.0) as f32,
                    rng.uniform(-1.0, 1.0) as f32,
                    rng.normal() as f32 * 0.01,
                )
            })
            .collect();
        pts.extend([Vec3::new(100.0, 0.0, 0.0), Vec3::new(-80.0, 50.0, 3.0)]);
        pts.push(pts[0]);
        let fast = mean_sq_knn(&pts, 3);
        let slow = brute(&pts, 3);
        for (a, b) in fast.iter().zip(&slow) {
            assert!((a - b).abs() <= 1e-5 * b.max(1e-6), "{a} vs {b}");
        }
        assert_eq!(mean_sq_knn(&pts[..1], 3), vec![1e-4]);
        assert_eq!(mean_sq_knn(&pts[..2], 3).len(), 2);
    }
}

#[cfg(test)]
mod budget_tests {
    use super::*;

    #[test]
    fn a_cloud_above_the_budget_is_sampled_down_and_one_below_kept() {
        let cloud = PointCloud {
            positions: (0..1000).map(|i| DVec3::new(i as f64, 0.0, 0.0)).collect(),
            colors: (0..1000).map(|i| [i as f32, 0.0, 0.0]).collect(),
        };
        assert_eq!(within_budget(&cloud, 1000, 1).len(), 1000);
        let a = within_budget(&cloud, 100, 7);
        assert_eq!(a.len(), 100);
        // Points keep their colours, stay in order, and are spread over the cloud.
        for (p, c) in a.positions.iter().zip(&a.colors) {
            assert_eq!(p.x as f32, c[0]);
        }
        assert!(a.positions.windows(2).all(|w| w[0].x < w[1].x));
        assert!(a.positions[0].x < 100.0 && a.positions[99].x > 900.0);
        // Seeded: the same seed, the same sample; another seed, another one.
        assert_eq!(a.positions, within_budget(&cloud, 100, 7).positions);
        assert_ne!(a.positions, within_budget(&cloud, 100, 8).positions);
    }
}
