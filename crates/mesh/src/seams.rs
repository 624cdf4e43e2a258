//! Seam levelling for the texture atlas (after Lempitsky & Ivanov, CVPR 2007, and the local
//! colour adjustment of Waechter et al., ECCV 2014): per-vertex colour offsets that make the charts
//! meeting at a vertex agree, spread into each chart by Jacobi diffusion.
//!
//! At a seam vertex (one original vertex with copies in charts of different views) every copy is
//! offset to the mean colour of all copies, and these offsets are fixed. The other vertices start
//! at zero and repeatedly take the mean offset of their neighbours (within their chart, since
//! copies are separate vertices), approaching the harmonic interpolation of the seam offsets, so a
//! brightness step between two views turns into a gentle ramp.

use handheld_core::TriMesh;

use crate::texture::TextureOptions;

/// Offsets per vertex of `out` and the mean colour disagreement at seam vertices before levelling.
/// `owner[i] = (chart, original vertex)` of new vertex `i`; `chart_views[c]` is `u32::MAX` for the
/// grey patch (never adjusted).
pub(crate) fn level(
    out: &TriMesh,
    chart_views: &[u32],
    owner: &[(u32, u32)],
    base: &[[f64; 3]],
    n_original: usize,
    opts: &TextureOptions,
) -> (Vec<[f64; 3]>, f64) {
    let n = owner.len();
    let mut offsets = vec![[0.0; 3]; n];
    // Copies of each original vertex, as CSR.
    let mut start = vec![0usize; n_original + 1];
    for &(_, v) in owner {
        start[v as usize + 1] += 1;
    }
    for i in 0..n_original {
        start[i + 1] += start[i];
    }
    let mut fill = start.clone();
    let mut copies = vec![0u32; n];
    for (i, &(_, v)) in owner.iter().enumerate() {
        copies[fill[v as usize]] = i as u32;
        fill[v as usize] += 1;
    }
    let mut fixed = vec![false; n];
    let (mut step_sum, mut seam_vertices) = (0.0, 0usize);
    for v in 0..n_original {
        let textured: Vec<u32> = copies[start[v]..start[v + 1]]
            .iter()
            .copied()
            .filter(|&i| chart_views[owner[i as usize].0 as usize] != u32::MAX)
            .collect();
        if textured.len() < 2 {
            continue;
        }
        let mut mean = [0.0; 3];
        for &i in &textured {
            for k in 0..3 {
                mean[k] += base[i as usize][k] / textured.len() as f64;
            }
        }
        let mut spread = 0.0;
        for &i in &textured {
            let b = base[i as usize];
            spread += (0..3).map(|k| (b[k] - mean[k]).abs()).sum::<f64>() / 3.0;
            if opts.blend_seams {
                offsets[i as usize] = std::array::from_fn(|k| mean[k] - b[k]);
            }
            fixed[i as usize] = true;
        }
        step_sum += 2.0 * spread / textured.len() as f64;
        seam_vertices += 1;
    }
    let seam_step = if seam_vertices > 0 {
        step_sum / seam_vertices as f64
    } else {
        0.0
    };
    if !opts.blend_seams || seam_vertices == 0 {
        return (offsets, seam_step);
    }
    for (i, &(c, _)) in owner.iter().enumerate() {
        if chart_views[c as usize] == u32::MAX {
            fixed[i] = true;
        }
    }
    // Vertex adjacency of the split mesh (CSR, duplicates harmless).
    let mut deg = vec![0usize; n + 1];
    for f in &out.faces {
        for &v in f {
            deg[v as usize + 1] += 2;
        }
    }
    for i in 0..n {
        deg[i + 1] += deg[i];
    }
    let mut pos = deg.clone();
    let mut adj = vec![0u32; deg[n]];
    for f in &out.faces {
        for k in 0..3 {
            let v = f[k] as usize;
            for j in [f[(k + 1) % 3], f[(k + 2) % 3]] {
                adj[pos[v]] = j;
                pos[v] += 1;
            }
        }
    }
    for _ in 0..opts.seam_rounds {
        let prev = offsets.clone();
        for i in 0..n {
            if fixed[i] || deg[i] == deg[i + 1] {
                continue;
            }
            let nb = &adj[deg[i]..deg[i + 1]];
            let mut acc = [0.0; 3];
            for &j in nb {
                for k in 0..3 {
                    acc[k] += prev[j as usize][k];
                }
            }
            offsets[i] = acc.map(|a| a / nb.len() as f64);
        }
    }
    (offsets, seam_step)
}
