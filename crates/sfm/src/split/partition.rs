//! The view graph cut into clusters of at most `cluster_views` views that overlap their
//! neighbours, as COLMAP's hierarchical mapper does (Schönberger & Frahm 2016, §4.4 "Scale";
//! Bhowmick et al. 2014, "Divide and conquer: efficient large-scale structure from motion using
//! graph partitioning", ACCV).
//!
//! * The graph: a node per image with keypoints and a verified pair, an edge per verified pair
//!   weighted by its inlier matches.
//! * The cut: recursive bisection by the normalised cut of Shi & Malik (2000, "Normalized cuts and
//!   image segmentation", PAMI): the generalised eigenvector `(D − W) y = λ D y` of the second
//!   smallest eigenvalue orders the views, and the split along that order with the smallest
//!   `cut(A, B) / assoc(A) + cut(A, B) / assoc(B)` (each side at least a quarter of the views) is
//!   taken. Components are cut apart first. Graphs of more than [`DENSE_EIGEN_MAX`] views are
//!   first halved along a breadth-first order from a pseudo-peripheral view (the level structure
//!   graph partitioners start from, George & Liu 1979), again with the smallest normalised cut.
//! * The overlap: each cluster is grown by the views outside it most strongly linked to it (the
//!   sum of their inlier matches into it), greedily, until it holds `overlap` times its own views
//!   more, within `cluster_views` in all. Those views are registered in both neighbours, and their
//!   keypoints tie the two models together (`merge.rs`).

use std::collections::{BTreeMap, BTreeSet, VecDeque};

use crate::input::SfmInput;

/// Largest graph whose Fiedler vector is found by a dense eigendecomposition (a few seconds).
pub const DENSE_EIGEN_MAX: usize = 3000;

/// The weighted view graph: `adj[i]` lists `(neighbour, weight)`.
pub(crate) struct ViewGraph {
    pub adj: Vec<Vec<(usize, f64)>>,
}

impl ViewGraph {
    pub fn new(input: &SfmInput) -> Self {
        let n = input.images.len();
        let mut w: BTreeMap<(usize, usize), f64> = BTreeMap::new();
        for p in &input.pairs {
            if p.a == p.b || p.a >= n || p.b >= n || p.matches.is_empty() {
                continue;
            }
            *w.entry((p.a.min(p.b), p.a.max(p.b))).or_default() += p.matches.len() as f64;
        }
        let mut adj = vec![Vec::new(); n];
        for (&(a, b), &x) in &w {
            adj[a].push((b, x));
            adj[b].push((a, x));
        }
        Self { adj }
    }
}

/// One cluster: its own views (`core`, disjoint from the other clusters') and all its views
/// (the core and the overlap), input indices in increasing order.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Cluster {
    pub core: Vec<usize>,
    pub views: Vec<usize>,
}

/// Cuts the images of `input` with a verified pair into clusters (see the module's text).
pub fn partition(input: &SfmInput, cluster_views: usize, overlap: f64) -> Vec<Cluster> {
    let g = ViewGraph::new(input);
    let nodes: Vec<usize> = (0..input.images.len())
        .filter(|&i| !g.adj[i].is_empty() && !input.images[i].keypoints.is_empty())
        .collect();
    let core_max = ((cluster_views as f64 / (1.0 + overlap)).floor() as usize).max(2);
    let mut cores = Vec::new();
    for comp in components(&g, &nodes) {
        if comp.len() >= 2 {
            bisect(&g, comp, core_max, &mut cores);
        }
    }
    cores.sort();
    let mut owner = vec![usize::MAX; input.images.len()];
    for (c, core) in cores.iter().enumerate() {
        for &i in core {
            owner[i] = c;
        }
    }
    cores
        .iter()
        .enumerate()
        .map(|(c, core)| {
            let views = grow(&g, &owner, c, core, overlap, cluster_views);
            Cluster {
                core: core.clone(),
                views,
            }
        })
        .collect()
}

/// The connected components of the graph restricted to `nodes`, each sorted.
fn components(g: &ViewGraph, nodes: &[usize]) -> Vec<Vec<usize>> {
    let inside: BTreeSet<usize> = nodes.iter().copied().collect();
    let mut seen = BTreeSet::new();
    let mut out = Vec::new();
    for &s in nodes {
        if !seen.insert(s) {
            continue;
        }
        let mut comp = vec![s];
        let mut queue = VecDeque::from([s]);
        while let Some(u) = queue.pop_front() {
            for &(v, _) in &g.adj[u] {
                if inside.contains(&v) && seen.insert(v) {
                    comp.push(v);
                    queue.push_back(v);
                }
            }
        }
        comp.sort_unstable();
        out.push(comp);
    }
    out
}

/// Recursive bisection of a connected set until each part holds at most `core_max` views.
fn bisect(g: &ViewGraph, nodes: Vec<usize>, core_max: usize, out: &mut Vec<Vec<usize>>) {
    if nodes.len() <= core_max {
        out.push(nodes);
        return;
    }
    let order = if nodes.len() <= DENSE_EIGEN_MAX {
        spectral_order(g, &nodes).unwrap_or_else(|| bfs_order(g, &nodes))
    } else {
        bfs_order(g, &nodes)
    };
    let k = best_split(g, &order, core_max);
    let (mut a, mut b) = (order[..k].to_vec(), order[k..].to_vec());
    a.sort_unstable();
    b.sort_unstable();
    // A side that fell apart is cut into its components first.
    for side in [a, b] {
        for comp in components(g, &side) {
            bisect(g, comp, core_max, out);
        }
    }
}

/// The nodes ordered by the generalised Fiedler vector `D^{-1/2} u₂` of the normalised Laplacian
/// `I − D^{-1/2} W D^{-1/2}` (Shi & Malik 2000, eq. 9), ties by index.
fn spectral_order(g: &ViewGraph, nodes: &[usize]) -> Option<Vec<usize>> {
    let n = nodes.len();
    let local: BTreeMap<usize, usize> = nodes.iter().enumerate().map(|(k, &i)| (i, k)).collect();
    let mut d = vec![0.0f64; n];
    let mut w = faer::Mat::<f64>::zeros(n, n);
    for (k, &i) in nodes.iter().enumerate() {
        for &(j, x) in &g.adj[i] {
            if let Some(&l) = local.get(&j) {
                w[(k, l)] = x;
                d[k] += x;
            }
        }
    }
    if d.iter().any(|&x| x <= 0.0) {
        return None;
    }
    let s: Vec<f64> = d.iter().map(|x| 1.0 / x.sqrt()).collect();
    let l = faer::Mat::<f64>::from_fn(n, n, |r, c| {
        let off = -w[(r, c)] * s[r] * s[c];
        if r == c {
            1.0 + off
        } else {
            off
        }
    });
    let eig = l.self_adjoint_eigen(faer::Side::Lower).ok()?;
    let u = eig.U();
    let y: Vec<f64> = (0..n).map(|k| u[(k, 1)] * s[k]).collect();
    if y.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| y[a].total_cmp(&y[b]).then(a.cmp(&b)));
    Some(order.into_iter().map(|k| nodes[k]).collect())
}

/// The nodes in breadth-first order from a pseudo-peripheral node (the last one reached by a
/// breadth-first search from the first node, twice).
fn bfs_order(g: &ViewGraph, nodes: &[usize]) -> Vec<usize> {
    let inside: BTreeSet<usize> = nodes.iter().copied().collect();
    let bfs = |s: usize| {
        let mut seen = BTreeSet::from([s]);
        let mut order = vec![s];
        let mut queue = VecDeque::from([s]);
        while let Some(u) = queue.pop_front() {
            let mut next: Vec<usize> = g.adj[u]
                .iter()
                .map(|&(v, _)| v)
                .filter(|v| inside.contains(v))
                .collect();
            next.sort_unstable();
            for v in next {
                if seen.insert(v) {
                    order.push(v);
                    queue.push_back(v);
                }
            }
        }
        order
    };
    let far = *bfs(nodes[0]).last().unwrap_or(&nodes[0]);
    let far = *bfs(far).last().unwrap_or(&far);
    bfs(far)
}

/// The split point `k` of `order` (the first `k` nodes against the rest) with the smallest
/// normalised cut, near the balanced split: the nodes need `m = ⌈n / core_max⌉` clusters, so the
/// first side should hold `⌊m/2⌋/m` of them; the cut may move a quarter of a cluster either way
/// (a free cut left 15 views as 11 + 4, and a cluster of 4 views barely overlaps its neighbours).
fn best_split(g: &ViewGraph, order: &[usize], core_max: usize) -> usize {
    let n = order.len();
    let pos: BTreeMap<usize, usize> = order.iter().enumerate().map(|(k, &i)| (i, k)).collect();
    let deg = |i: usize| -> f64 {
        g.adj[i]
            .iter()
            .filter(|(j, _)| pos.contains_key(j))
            .map(|x| x.1)
            .sum()
    };
    let total: f64 = order.iter().map(|&i| deg(i)).sum();
    let m = n.div_ceil(core_max.max(1)).max(2);
    let target = n * (m / 2) / m;
    let slack = (n / (4 * m)).max(1);
    // Neither side may need more clusters than it is given (⌊m/2⌋ and ⌈m/2⌉).
    let (left_max, right_max) = ((m / 2) * core_max, (m - m / 2) * core_max);
    let lo = target
        .saturating_sub(slack)
        .max(n.saturating_sub(right_max))
        .max(1);
    let hi = (target + slack).min(left_max).min(n - 1).max(lo);
    let mut cut = 0.0;
    let mut assoc_a = 0.0;
    let mut best = (f64::INFINITY, n / 2);
    for k in 1..n {
        // Node order[k−1] moves to side A.
        let u = order[k - 1];
        for &(v, x) in &g.adj[u] {
            if let Some(&p) = pos.get(&v) {
                if p < k - 1 {
                    cut -= x;
                } else {
                    cut += x;
                }
            }
        }
        assoc_a += deg(u);
        if k < lo || k > hi {
            continue;
        }
        let assoc_b = total - assoc_a;
        let ncut = if assoc_a > 0.0 && assoc_b > 0.0 {
            cut / assoc_a + cut / assoc_b
        } else {
            f64::INFINITY
        };
        if ncut < best.0 {
            best = (ncut, k);
        }
    }
    best.1
}

/// `core` (cluster `me`) grown by the views most strongly linked to it, until it holds
/// `overlap · |core|` more or `cluster_views` in all. Each neighbouring cluster lends a share in
/// proportion to the matches across the cut between the two, at least a few views, so that a
/// cluster overlaps every neighbour it must be merged with, not only its strongest one (a greedy
/// growth would follow one side of a chain).
fn grow(
    g: &ViewGraph,
    owner: &[usize],
    me: usize,
    core: &[usize],
    overlap: f64,
    cluster_views: usize,
) -> Vec<usize> {
    let mut inside: BTreeSet<usize> = core.iter().copied().collect();
    let want = ((overlap * core.len() as f64).ceil() as usize)
        .min(cluster_views.saturating_sub(core.len()));
    // The matches across the cut to each neighbouring cluster.
    let mut cut: BTreeMap<usize, f64> = BTreeMap::new();
    for &u in core {
        for &(v, x) in &g.adj[u] {
            if owner[v] != me && owner[v] != usize::MAX {
                *cut.entry(owner[v]).or_default() += x;
            }
        }
    }
    let total: f64 = cut.values().sum();
    // Each neighbour's share: in proportion to its cut, at least MIN_SHARE; the strongest first.
    let mut shares: Vec<(usize, usize)> = cut
        .iter()
        .map(|(&n, &w)| {
            (
                n,
                ((want as f64 * w / total).round() as usize).max(MIN_SHARE),
            )
        })
        .collect();
    shares.sort_by(|a, b| cut[&b.0].total_cmp(&cut[&a.0]).then(a.0.cmp(&b.0)));
    // The views are handed out one round at a time, a view to each neighbour that still has a
    // share, so that when the cluster's size limit runs short every neighbour still gets some.
    let budget = want
        .max(MIN_SHARE * shares.len())
        .min(cluster_views.saturating_sub(core.len()));
    let mut given = vec![0usize; shares.len()];
    let mut left = budget;
    while left > 0 {
        let mut progressed = false;
        for (s, &(n, share)) in shares.iter().enumerate() {
            if left == 0 || given[s] >= share {
                continue;
            }
            // The neighbour's view with the most matches into the cluster as it is now.
            let best = inside
                .iter()
                .flat_map(|&u| g.adj[u].iter())
                .filter(|(v, _)| owner[*v] == n && !inside.contains(v))
                .fold(BTreeMap::<usize, f64>::new(), |mut m, &(v, x)| {
                    *m.entry(v).or_default() += x;
                    m
                })
                .into_iter()
                .max_by(|a, b| a.1.total_cmp(&b.1).then(b.0.cmp(&a.0)));
            if let Some((v, _)) = best {
                inside.insert(v);
                given[s] += 1;
                left -= 1;
                progressed = true;
            } else {
                given[s] = share;
            }
        }
        if !progressed {
            break;
        }
    }
    inside.into_iter().collect()
}

/// Fewest views a cluster borrows from each neighbour (a merge needs views both registered).
const MIN_SHARE: usize = 3;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::input::{SfmImage, SfmPair};
    use handheld_core::ImageId;
    use handheld_robust::TwoViewConfiguration;
    use nalgebra::Vector2;

    /// A loop of `n` views, each linked to its `w` neighbours on either side with weights that
    /// fall with the distance.
    fn ring(n: usize, w: usize) -> SfmInput {
        let images = (0..n)
            .map(|i| SfmImage {
                id: ImageId(i as u32),
                name: format!("{i}"),
                width: 64,
                height: 48,
                keypoints: vec![Vector2::new(1.0, 1.0); 4],
                keypoint_scales: Vec::new(),
                camera_key: "c".into(),
                focal_prior_px: None,
                frame: None,
                track_ids: Vec::new(),
                descriptors: Vec::new(),
                descriptor_dim: 0,
            })
            .collect();
        let mut pairs = Vec::new();
        for i in 0..n {
            for d in 1..=w {
                let j = (i + d) % n;
                pairs.push(SfmPair {
                    a: i.min(j),
                    b: i.max(j),
                    matches: vec![(0, 0); 100 / d],
                    f: None,
                    configuration: TwoViewConfiguration::General,
                    view_distance_px: None,
                });
            }
        }
        SfmInput {
            images,
            pairs,
            video: false,
        }
    }

    #[test]
    fn a_loop_is_cut_into_contiguous_arcs_that_overlap() {
        let input = ring(120, 4);
        let clusters = partition(&input, 26, 0.3);
        // Every view is in exactly one core; each core is at most 26 / 1.3 = 20 views.
        let mut all: Vec<usize> = clusters.iter().flat_map(|c| c.core.clone()).collect();
        all.sort_unstable();
        assert_eq!(all, (0..120).collect::<Vec<_>>());
        assert!(clusters.len() >= 6, "{} clusters", clusters.len());
        for c in &clusters {
            assert!(c.core.len() <= 20 && c.views.len() <= 26, "{c:?}");
            // The core is an arc: its views form one run along the loop (at most one wrap).
            let breaks = c.core.windows(2).filter(|w| w[1] != w[0] + 1).count();
            assert!(breaks <= 1, "core {:?} is not an arc", c.core);
            // The overlap is about 30 % of the core, taken from both neighbours.
            let extra: Vec<usize> = c
                .views
                .iter()
                .filter(|v| !c.core.contains(v))
                .copied()
                .collect();
            let want = (0.3 * c.core.len() as f64).ceil() as usize;
            assert!(extra.len() <= want && extra.len() + 1 >= want, "{c:?}");
            let before = extra
                .iter()
                .filter(|&&v| (v + 120 - c.core[0]) % 120 > 60)
                .count();
            assert!(
                before >= 2 && extra.len() - before >= 2,
                "one-sided overlap {c:?}"
            );
        }
    }

    #[test]
    fn components_are_cut_apart_and_the_bfs_order_agrees() {
        // Two loops with no pair between them.
        let mut input = ring(40, 3);
        let second = ring(40, 3);
        let off = input.images.len();
        for (k, mut im) in second.images.into_iter().enumerate() {
            im.id = ImageId((off + k) as u32);
            input.images.push(im);
        }
        for mut p in second.pairs {
            p.a += off;
            p.b += off;
            input.pairs.push(p);
        }
        let clusters = partition(&input, 1000, 0.3);
        assert_eq!(clusters.len(), 2);
        assert_eq!(clusters[0].core, (0..40).collect::<Vec<_>>());
        let g = ViewGraph::new(&input);
        let nodes: Vec<usize> = (0..40).collect();
        let k = best_split(&g, &bfs_order(&g, &nodes), 20);
        assert!((10..=30).contains(&k));
    }
}
