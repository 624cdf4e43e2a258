//! The second round of pair selection for photo sets matched selectively (retrieval, or the
//! window over the content order plus retrieval): an image whose first round verified fewer pairs
//! than a sequence's window would give is matched with every other image.
//!
//! Retrieval ranks images by a global descriptor (`retrieval.rs`), and where every image shows the
//! same object and ground, the ranking misses whole viewpoints: on a synthetic hemisphere of 48
//! views at an 11° field of view (`handheld demo --path hemisphere --fov 11`, seed 0), the first
//! round proposed 465 of the 1 128 pairs and never paired the lowest ring with the ring above
//! (pairs that verify with up to 386 inliers when every pair is matched). Those views verified 2–7
//! pairs each, against 15–25 for every frame of kitti-seq1, whose proposals verify almost all. A
//! view with few verified pairs is the one whose proposals failed, or one that overlaps few
//! others; either way its full row costs at most `n − 1` pairs and finds what retrieval missed.
//! Images that share verified neighbours (COLMAP's transitive matching) were tried first: that
//! found 194 more pairs on the same hemisphere, none of them between the two rings, and 372 on
//! kitti-seq1, where they only added time.

/// Every pair not yet `tried` that has an image with fewer than `min_verified` pairs in `verified`
/// among the `n` images, as `(lower, higher)`, sorted, without duplicates.
pub fn weak_image_pairs(
    n: usize,
    verified: &[(usize, usize)],
    tried: &[(usize, usize)],
    min_verified: usize,
) -> Vec<(usize, usize)> {
    let mut count = vec![0usize; n];
    for &(i, j) in verified {
        if i < n && j < n && i != j {
            count[i] += 1;
            count[j] += 1;
        }
    }
    let done: std::collections::HashSet<(usize, usize)> =
        tried.iter().map(|&(a, b)| (a.min(b), a.max(b))).collect();
    let mut out: Vec<(usize, usize)> = (0..n)
        .filter(|&a| count[a] < min_verified)
        .flat_map(|a| {
            (0..n)
                .filter(move |&b| b != a)
                .map(move |b| (a.min(b), a.max(b)))
        })
        .filter(|k| !done.contains(k))
        .collect();
    out.sort_unstable();
    out.dedup();
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_the_rows_of_weakly_verified_images_are_added_and_tried_pairs_never() {
        // Five images: 0–1, 1–2, 0–2 and 2–3 verified, 4 verified nothing. With at least two
        // verified pairs needed, 3 and 4 are weak: their rows, without the pairs already tried.
        let verified = [(0, 1), (1, 2), (0, 2), (2, 3)];
        let tried = [(0, 1), (1, 2), (0, 2), (2, 3), (3, 4), (0, 4)];
        let p = weak_image_pairs(5, &verified, &tried, 2);
        assert_eq!(p, vec![(0, 3), (1, 3), (1, 4), (2, 4)]);
        // Nothing is weak with no minimum.
        assert!(weak_image_pairs(5, &verified, &tried, 0).is_empty());
    }
}
