//! The sparse points a pair's disparity range comes from (§4.1: the range is bounded by the
//! structure that is already known).
//!
//! Every sparse point in both frusta used to count. A two-view point is one match, and on
//! repetitive structure a wrong match can agree with the epipolar geometry: on templeSparseRing
//! such points lie up to 8 m away from an object 3 m from the cameras, and they widened ranges
//! to 1 400 disparities where the object spans 200. Wider ranges cost time and, on a dark
//! background, let the matcher find more wrong minima. A point that a third view confirms is
//! one such a mismatch rarely makes, and a point that the pair's own views observed is not hidden
//! from them. So the range comes from, in this order, the first set with at least
//! [`MIN_RANGE_POINTS`] points:
//! 1. points seen by at least three views, both views of the pair among them;
//! 2. points the pair's own views both observed, two-view points included: verified by this
//!    pair's geometry, and the only points certain to lie in both views. A view that shares
//!    points with one other view only (iclnuim-5's 3.png and 1.png share 233 two-view points)
//!    otherwise got the range of set 3, whose points lay outside its frustum, and no depth;
//! 3. points seen by at least three views, one view of the pair among them;
//! 4. every point (also where the views that saw each point are unknown).

use handheld_core::{ImageId, Point3D};
use nalgebra::Point3;

/// The fewest points a selection needs before the range is taken from it (the range trims
/// 1 % of the image area at each end: a few dozen points make that meaningful).
pub const MIN_RANGE_POINTS: usize = 20;

/// Views a point needs before it is trusted to bound a range.
const CONFIRMED_VIEWS: usize = 3;

/// Sparse points with the views (indices into the dense stage's sequence) that observed each.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SparsePoints {
    pub xyz: Vec<Point3<f64>>,
    /// For each point, the sorted indices of the views that observed it; empty where unknown.
    pub seen_by: Vec<Vec<u32>>,
}

impl SparsePoints {
    /// Points whose observers are unknown: every range uses them all.
    pub fn unobserved(xyz: Vec<Point3<f64>>) -> Self {
        let seen_by = vec![Vec::new(); xyz.len()];
        Self { xyz, seen_by }
    }

    /// The points of a model, with observers given as positions in `sequence` (the views the
    /// dense stage is given, in its order); observations by views outside it are not counted.
    pub fn from_tracks<'a>(
        points: impl IntoIterator<Item = &'a Point3D>,
        sequence: &[ImageId],
    ) -> Self {
        let index: std::collections::HashMap<ImageId, u32> = sequence
            .iter()
            .enumerate()
            .map(|(i, id)| (*id, i as u32))
            .collect();
        let mut out = Self::default();
        for p in points {
            let mut seen: Vec<u32> = p
                .track
                .elements
                .iter()
                .filter_map(|e| index.get(&e.image_id).copied())
                .collect();
            seen.sort_unstable();
            seen.dedup();
            out.xyz.push(p.xyz);
            out.seen_by.push(seen);
        }
        out
    }

    pub fn len(&self) -> usize {
        self.xyz.len()
    }

    pub fn is_empty(&self) -> bool {
        self.xyz.is_empty()
    }

    /// The points that bound the disparity range of views `a` and `b` (see the module
    /// documentation).
    pub fn for_pair(&self, a: usize, b: usize) -> Vec<Point3<f64>> {
        let (a, b) = (a as u32, b as u32);
        let confirmed = |s: &Vec<u32>| s.len() >= CONFIRMED_VIEWS;
        let observed = |s: &Vec<u32>| s.binary_search(&a).is_ok() && s.binary_search(&b).is_ok();
        let both = |s: &Vec<u32>| confirmed(s) && observed(s);
        let either = |s: &Vec<u32>| {
            confirmed(s) && (s.binary_search(&a).is_ok() || s.binary_search(&b).is_ok())
        };
        for keep in [&both as &dyn Fn(&Vec<u32>) -> bool, &observed, &either] {
            let n = self.seen_by.iter().filter(|s| keep(s)).count();
            if n >= MIN_RANGE_POINTS {
                return self
                    .xyz
                    .iter()
                    .zip(&self.seen_by)
                    .filter(|(_, s)| keep(s))
                    .map(|(p, _)| *p)
                    .collect();
            }
        }
        self.xyz.clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn set(seen: &[&[u32]]) -> SparsePoints {
        SparsePoints {
            xyz: (0..seen.len())
                .map(|i| Point3::new(i as f64, 0.0, 1.0))
                .collect(),
            seen_by: seen.iter().map(|s| s.to_vec()).collect(),
        }
    }

    fn ids(p: &[Point3<f64>]) -> Vec<usize> {
        p.iter().map(|q| q.x as usize).collect()
    }

    #[test]
    fn confirmed_points_of_the_pair_come_first() {
        // 20 points three views confirm, both of the pair among them; 5 two-view matches of the
        // pair; 30 confirmed points of other views.
        let mut seen: Vec<&[u32]> = vec![&[0, 1, 2]; 20];
        seen.extend(vec![&[0u32, 1][..]; 5]);
        seen.extend(vec![&[3u32, 4, 5][..]; 30]);
        let p = set(&seen);
        assert_eq!(ids(&p.for_pair(0, 1)), (0..20).collect::<Vec<_>>());
    }

    #[test]
    fn a_pair_without_confirmed_points_takes_its_own_two_view_points() {
        // Views 0 and 1 share only two-view points (25); view 1 has 30 confirmed points with
        // views 2 and 3 that view 0 may not see.
        let mut seen: Vec<&[u32]> = vec![&[0, 1]; 25];
        seen.extend(vec![&[1u32, 2, 3][..]; 30]);
        let p = set(&seen);
        assert_eq!(ids(&p.for_pair(0, 1)), (0..25).collect::<Vec<_>>());
    }

    #[test]
    fn too_few_falls_back_to_either_view_then_to_all() {
        // 19 confirmed by both, 1 confirmed by view 1 only: the second set (20).
        let mut seen: Vec<&[u32]> = vec![&[0, 1, 2]; 19];
        seen.push(&[1, 2, 3]);
        seen.extend(vec![&[3u32, 4, 5][..]; 10]);
        let p = set(&seen);
        assert_eq!(ids(&p.for_pair(0, 1)), (0..20).collect::<Vec<_>>());
        // A pair that few confirmed points see: every point.
        assert_eq!(p.for_pair(6, 7).len(), 30);
        // Unknown observers: every point.
        let u = SparsePoints::unobserved(p.xyz.clone());
        assert_eq!(u.for_pair(0, 1).len(), 30);
    }
}
