//! Longer tracks (§3.2, "refine the existing structure"): a point created from one pair is, through
//! the correspondence graph, often also matched in registered views that were never asked about it,
//! or split into two points by two different pairs. Completing and merging tracks gives every point
//! all the views that see it, which is what makes the structure (and the cameras adjusted with it)
//! accurate: the multi-view refinement of eq. 20 and the bundle adjustment of eq. 21 then use every
//! measurement. An observation joins a point only when the point reprojects within the threshold
//! there, and two points merge only when each explains all observations of the other and they share
//! no view.

use crate::context::Context;
use crate::projective::model::{ProjectiveModel, NONE};

/// What [`ProjectiveModel::complete_and_merge_tracks`] changed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct TrackGrowth {
    pub added: usize,
    pub merged: usize,
}

impl ProjectiveModel {
    /// Extends every point to the registered views its observations are matched to, following the
    /// graph transitively, and merges points that turn out to be the same.
    pub(crate) fn complete_and_merge_tracks(&mut self, ctx: &Context) -> TrackGrowth {
        let mut growth = TrackGrowth::default();
        for pid in 0..self.points.len() {
            let Some(pt) = self.points[pid].as_ref() else {
                continue;
            };
            let mut queue = pt.obs.clone();
            let mut changed = false;
            let mut q = 0;
            while q < queue.len() {
                let (i, k) = queue[q];
                q += 1;
                for &(j, kj) in ctx.graph.correspondences(i as usize, k as usize) {
                    if self.cams[j as usize].is_none() {
                        continue;
                    }
                    let cur = self.kp_point[j as usize][kj as usize];
                    let Some(p) = self.points[pid].as_ref() else {
                        break;
                    };
                    if cur == pid as u32 || p.obs.iter().any(|o| o.0 == j) {
                        continue;
                    }
                    let m = p.m;
                    if cur == NONE {
                        if self.obs_error(ctx, &m, j, kj) < ctx.threshold(j as usize) {
                            self.kp_point[j as usize][kj as usize] = pid as u32;
                            if let Some(p) = self.points[pid].as_mut() {
                                p.obs.push((j, kj));
                            }
                            queue.push((j, kj));
                            growth.added += 1;
                            changed = true;
                        }
                        continue;
                    }
                    let Some(other) = self.points[cur as usize].as_ref() else {
                        continue;
                    };
                    let shares_view = other.obs.iter().any(|o| p.obs.iter().any(|a| a.0 == o.0));
                    if shares_view {
                        continue;
                    }
                    let fits_other = other
                        .obs
                        .iter()
                        .all(|&(a, b)| self.obs_error(ctx, &m, a, b) < ctx.threshold(a as usize));
                    let om = other.m;
                    let fits_self = p
                        .obs
                        .iter()
                        .all(|&(a, b)| self.obs_error(ctx, &om, a, b) < ctx.threshold(a as usize));
                    if !(fits_other && fits_self) {
                        continue;
                    }
                    if let Some(other) = self.points[cur as usize].take() {
                        for &(a, b) in &other.obs {
                            self.kp_point[a as usize][b as usize] = pid as u32;
                            queue.push((a, b));
                        }
                        if let Some(p) = self.points[pid].as_mut() {
                            p.obs.extend(other.obs);
                        }
                        growth.merged += 1;
                        changed = true;
                    }
                }
            }
            if changed {
                self.refine_point(ctx, pid);
            }
        }
        growth
    }
}
