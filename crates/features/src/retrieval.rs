//! Image retrieval for pair selection: which images of a large photo set to match, whatever order
//! their files come in. Every image gets one global descriptor, a VLAD vector (Jégou et al.,
//! "Aggregating local descriptors into a compact image representation", CVPR 2010) built from its
//! RootSIFT descriptors over a small vocabulary learnt by k-means on the set itself, with
//! intra-normalisation and signed square roots (Arandjelović & Zisserman, "All about VLAD",
//! CVPR 2013). Each image is then paired with the images whose vectors are most similar (cosine),
//! which finds the views that overlap, including a camera coming back to a place it saw before
//! (§3.2's close views), without matching every pair.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::detector::Features;
use crate::error::FeatureError;

/// Options of [`retrieval_pairs`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct RetrievalOptions {
    /// Most similar images paired with each image.
    pub neighbours: usize,
    /// Visual words of the VLAD vocabulary.
    pub words: usize,
    /// Strongest descriptors per image that describe it (and train the vocabulary).
    pub descriptors_per_image: usize,
    /// Descriptors the vocabulary is trained on, sampled evenly from all images.
    pub training_descriptors: usize,
    /// Lloyd iterations of k-means.
    pub iterations: usize,
    /// Seed of the k-means++ initialisation.
    pub seed: u64,
}

impl Default for RetrievalOptions {
    fn default() -> Self {
        Self {
            neighbours: 15,
            words: 64,
            descriptors_per_image: 2000,
            training_descriptors: 50_000,
            iterations: 10,
            seed: 0,
        }
    }
}

impl RetrievalOptions {
    /// Checks option ranges; the error names the option.
    pub fn validate(&self) -> Result<(), FeatureError> {
        let bad = |option: &'static str, reason: &str| {
            Err(FeatureError::InvalidOption {
                option,
                reason: reason.into(),
            })
        };
        if self.neighbours == 0 {
            return bad("neighbours", "must be at least 1");
        }
        if self.words < 2 {
            return bad("words", "must be at least 2");
        }
        if self.descriptors_per_image == 0 || self.training_descriptors < self.words {
            return bad(
                "training_descriptors",
                "must be at least `words`, with descriptors_per_image at least 1",
            );
        }
        Ok(())
    }
}

/// Indices of the `n` strongest keypoints that have a descriptor.
fn strongest(f: &Features, n: usize) -> Vec<usize> {
    let mut idx: Vec<usize> = (0..f.keypoints.len().min(f.descriptors.len())).collect();
    idx.sort_by(|&a, &b| {
        f.keypoints[b]
            .response
            .total_cmp(&f.keypoints[a].response)
            .then(a.cmp(&b))
    });
    idx.truncate(n);
    idx
}

fn dist2(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum()
}

/// Words per lane group of [`Vocabulary`].
const LANES: usize = 8;

/// The visual words laid out for [`Vocabulary::nearest`]: groups of [`LANES`] words, each group
/// dimension-major (`groups[g][i][k]` is dimension `i` of word `g·LANES + k`), the last group
/// padded with words at infinity.
struct Vocabulary {
    groups: Vec<Vec<[f32; LANES]>>,
}

impl Vocabulary {
    fn new(words: &[Vec<f32>]) -> Self {
        let dim = words.first().map_or(0, Vec::len);
        let groups = words
            .chunks(LANES)
            .map(|g| {
                (0..dim)
                    .map(|i| std::array::from_fn(|k| g.get(k).map_or(f32::INFINITY, |w| w[i])))
                    .collect()
            })
            .collect();
        Self { groups }
    }

    /// The nearest word of `d`: the first of the smallest squared distances, each summed over
    /// the dimensions in order as [`dist2`] sums it, so the same word. The words of a group are
    /// summed side by side (one lane each): a distance is a chain of dependent additions, and
    /// one at a time it ran at the adder's latency (8 % of kitti-seq1's matches stage).
    fn nearest(&self, d: &[f32]) -> usize {
        let mut best = (0, f32::INFINITY);
        for (g, group) in self.groups.iter().enumerate() {
            let mut acc = [0f32; LANES];
            for (w, &x) in group.iter().zip(d) {
                for k in 0..LANES {
                    let e = w[k] - x;
                    acc[k] += e * e;
                }
            }
            for (k, &e) in acc.iter().enumerate() {
                if e < best.1 {
                    best = (g * LANES + k, e);
                }
            }
        }
        best.0
    }
}

/// SplitMix64: a tiny seeded generator for the k-means++ draws.
struct SplitMix(u64);

impl SplitMix {
    fn next_f64(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// k-means with k-means++ seeding (Arthur & Vassilvitskii 2007) on the rows of `data`.
fn kmeans(data: &[&[f32]], k: usize, iterations: usize, seed: u64) -> Vec<Vec<f32>> {
    let mut rng = SplitMix(seed);
    let mut words: Vec<Vec<f32>> = vec![data[0].to_vec()];
    let mut d2: Vec<f32> = data.iter().map(|d| dist2(d, &words[0])).collect();
    while words.len() < k.min(data.len()) {
        let total: f64 = d2.iter().map(|&v| f64::from(v)).sum();
        let mut target = rng.next_f64() * total;
        let mut pick = data.len() - 1;
        for (i, &v) in d2.iter().enumerate() {
            target -= f64::from(v);
            if target <= 0.0 {
                pick = i;
                break;
            }
        }
        words.push(data[pick].to_vec());
        let w = words.last().map(Vec::as_slice).unwrap_or(&[]);
        d2.par_iter_mut()
            .zip(data.par_iter())
            .for_each(|(e, d)| *e = e.min(dist2(d, w)));
    }
    let dim = data[0].len();
    for _ in 0..iterations {
        let vocabulary = Vocabulary::new(&words);
        let labels: Vec<usize> = data.par_iter().map(|d| vocabulary.nearest(d)).collect();
        let mut sums = vec![vec![0f64; dim]; words.len()];
        let mut counts = vec![0usize; words.len()];
        for (d, &l) in data.iter().zip(&labels) {
            counts[l] += 1;
            for (s, &v) in sums[l].iter_mut().zip(d.iter()) {
                *s += f64::from(v);
            }
        }
        for ((w, s), &c) in words.iter_mut().zip(&sums).zip(&counts) {
            if c > 0 {
                for (wv, sv) in w.iter_mut().zip(s) {
                    *wv = (sv / c as f64) as f32;
                }
            }
        }
    }
    words
}

/// The VLAD vector of one image: per word, the sum of its descriptors' residuals, each block
/// L2-normalised (intra-normalisation), then signed square roots and a global L2 normalisation.
fn vlad(f: &Features, idx: &[usize], words: &[Vec<f32>], vocabulary: &Vocabulary) -> Vec<f32> {
    let dim = f.descriptors.dim;
    let mut v = vec![0f32; words.len() * dim];
    for &i in idx {
        let d = f.descriptors.row(i);
        let k = vocabulary.nearest(d);
        for (o, (x, w)) in v[k * dim..(k + 1) * dim]
            .iter_mut()
            .zip(d.iter().zip(&words[k]))
        {
            *o += x - w;
        }
    }
    for block in v.chunks_mut(dim) {
        let n = block.iter().map(|x| x * x).sum::<f32>().sqrt();
        if n > 0.0 {
            block.iter_mut().for_each(|x| *x /= n);
        }
    }
    v.iter_mut().for_each(|x| *x = x.signum() * x.abs().sqrt());
    let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
    if n > 0.0 {
        v.iter_mut().for_each(|x| *x /= n);
    }
    v
}

/// Every image's VLAD vector (empty for an image without descriptors). The vocabulary is trained
/// on the images taken in the order of their content keys ([`crate::verify::content_key`]), so the
/// vectors do not depend on the files' names or order.
pub fn global_descriptors(
    features: &[Features],
    opts: &RetrievalOptions,
) -> Result<Vec<Vec<f32>>, FeatureError> {
    opts.validate()?;
    let n = features.len();
    let chosen: Vec<Vec<usize>> = features
        .iter()
        .map(|f| strongest(f, opts.descriptors_per_image))
        .collect();
    let total: usize = chosen.iter().map(Vec::len).sum();
    if n < 2 || total < opts.words {
        return Ok(vec![Vec::new(); n]);
    }
    let canonical = content_order(features);
    // An even sample of every image's chosen descriptors trains the vocabulary.
    let step = total.div_ceil(opts.training_descriptors).max(1);
    let training: Vec<&[f32]> = canonical
        .iter()
        .flat_map(|&k| {
            chosen[k]
                .iter()
                .map(move |&i| features[k].descriptors.row(i))
        })
        .step_by(step)
        .collect();
    let words = kmeans(&training, opts.words, opts.iterations, opts.seed);
    let vocabulary = Vocabulary::new(&words);
    Ok(features
        .par_iter()
        .zip(&chosen)
        .map(|(f, idx)| {
            if idx.is_empty() {
                Vec::new()
            } else {
                vlad(f, idx, &words, &vocabulary)
            }
        })
        .collect())
}

/// The image indices in the order of their content keys ([`crate::verify::content_key`]).
fn content_order(features: &[Features]) -> Vec<usize> {
    let keys: Vec<u64> = features
        .par_iter()
        .map(crate::verify::content_key)
        .collect();
    let mut order: Vec<usize> = (0..features.len()).collect();
    order.sort_by_key(|&i| (keys[i], i));
    order
}

fn cosine(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Each image's `k` most similar images, best first (ties by index).
fn nearest_images(vectors: &[Vec<f32>], k: usize) -> Vec<Vec<(f32, usize)>> {
    let n = vectors.len();
    (0..n)
        .into_par_iter()
        .map(|i| {
            if vectors[i].is_empty() {
                return Vec::new();
            }
            let mut sims: Vec<(f32, usize)> = (0..n)
                .filter(|&j| j != i && !vectors[j].is_empty())
                .map(|j| (cosine(&vectors[i], &vectors[j]), j))
                .collect();
            sims.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
            sims.truncate(k);
            sims
        })
        .collect()
}

/// The pairs `(i, j)`, `i < j`, of every image with its `neighbours` most similar images (by VLAD
/// cosine similarity; ties broken by index, so the result depends on the images, not on their
/// order beyond that). Images without descriptors get no pairs.
pub fn retrieval_pairs(
    features: &[Features],
    opts: &RetrievalOptions,
) -> Result<Vec<(usize, usize)>, FeatureError> {
    let vectors = global_descriptors(features, opts)?;
    Ok(most_similar_pairs(&vectors, opts.neighbours))
}

fn most_similar_pairs(vectors: &[Vec<f32>], neighbours: usize) -> Vec<(usize, usize)> {
    let mut pairs: Vec<(usize, usize)> = nearest_images(vectors, neighbours)
        .iter()
        .enumerate()
        .flat_map(|(i, list)| list.iter().map(move |&(_, j)| (i.min(j), i.max(j))))
        .collect();
    pairs.sort_unstable();
    pairs.dedup();
    pairs
}

/// Most images [`capture_order`] orders (a dense eigen-decomposition of n × n).
pub const MAX_SERIATION_IMAGES: usize = 2000;

/// An order of the images recovered from their content: spectral seriation (Atkins, Boman &
/// Hendrickson, "A spectral algorithm for seriation and the consecutive ones problem", SIAM J.
/// Comput. 1998). The graph links each image with its `neighbours` most similar ones (VLAD cosine),
/// and the images are sorted by the Fiedler vector of its normalised Laplacian. Photos taken
/// walking along a path come back in the order they were taken (or reversed, which gives the
/// same sequential pairs), whatever their file names. `None` beyond
/// [`MAX_SERIATION_IMAGES`] or without descriptors.
pub fn capture_order(
    features: &[Features],
    opts: &RetrievalOptions,
) -> Result<Option<Vec<usize>>, FeatureError> {
    let vectors = global_descriptors(features, opts)?;
    Ok(order_of(features, &vectors, opts.neighbours))
}

/// [`capture_order`] from the images' VLAD vectors.
fn order_of(features: &[Features], vectors: &[Vec<f32>], neighbours: usize) -> Option<Vec<usize>> {
    let n = features.len();
    if !(3..=MAX_SERIATION_IMAGES).contains(&n) || vectors.iter().any(Vec::is_empty) {
        return None;
    }
    // Computed in content order, so that the eigenvector's rounding cannot depend on file order.
    let canonical = content_order(features);
    let mut pos = vec![0usize; n];
    for (k, &i) in canonical.iter().enumerate() {
        pos[i] = k;
    }
    let near = nearest_images(vectors, neighbours);
    // A tiny weight between every pair keeps the graph connected.
    let mut w = nalgebra::DMatrix::<f64>::from_element(n, n, 1e-6);
    for (i, list) in near.iter().enumerate() {
        for &(s, j) in list {
            let v = f64::from(s).max(1e-6);
            let (a, b) = (pos[i], pos[j]);
            w[(a, b)] = w[(a, b)].max(v);
            w[(b, a)] = w[(b, a)].max(v);
        }
    }
    for k in 0..n {
        w[(k, k)] = 0.0;
    }
    let d: Vec<f64> = (0..n).map(|k| w.row(k).sum().max(1e-12)).collect();
    let mut l = nalgebra::DMatrix::<f64>::identity(n, n);
    for a in 0..n {
        for b in 0..n {
            l[(a, b)] -= w[(a, b)] / (d[a] * d[b]).sqrt();
        }
    }
    let eig = nalgebra::SymmetricEigen::new(l);
    let mut idx: Vec<usize> = (0..n).collect();
    idx.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    let fiedler = eig.eigenvectors.column(idx[1]);
    let value = |k: usize| fiedler[k] / d[k].sqrt();
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| value(a).total_cmp(&value(b)).then(a.cmp(&b)));
    Some(order.into_iter().map(|k| canonical[k]).collect())
}

/// Pairs for a large photo set, whatever the files' order: each image with the next `window`
/// images of the [`capture_order`] (the sequential window of a video, on the order the content
/// gives), and with its most similar images ([`retrieval_pairs`]), which link the views a path
/// passes twice and the rings of a hemisphere that the order puts apart.
pub fn unordered_pairs(
    features: &[Features],
    window: usize,
    opts: &RetrievalOptions,
) -> Result<Vec<(usize, usize)>, FeatureError> {
    let vectors = global_descriptors(features, opts)?;
    let mut pairs = most_similar_pairs(&vectors, opts.neighbours);
    if let Some(order) = order_of(features, &vectors, opts.neighbours) {
        for (a, &i) in order.iter().enumerate() {
            for &j in order.iter().skip(a + 1).take(window) {
                pairs.push((i.min(j), i.max(j)));
            }
        }
    }
    pairs.sort_unstable();
    pairs.dedup();
    Ok(pairs)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::detector::{Descriptors, Keypoint};

    /// `places` places with their own random unit descriptors; image `k` of a ring sees places
    /// k−1, k and k+1 (mod n) with a little noise, so its true neighbours are k ± 1 and k ± 2.
    fn ring(n: usize, seed: u64) -> Vec<Features> {
        scene(n, seed, true)
    }

    /// `n` images, image k seeing places k − 1, k and k + 1: around a ring when `closed`, else
    /// along a path.
    fn scene(n: usize, seed: u64, closed: bool) -> Vec<Features> {
        let dim = 32;
        let mut rng = SplitMix(seed);
        let places: Vec<Vec<Vec<f32>>> = (0..n)
            .map(|_| {
                (0..80)
                    .map(|_| (0..dim).map(|_| rng.next_f64() as f32).collect())
                    .collect()
            })
            .collect();
        (0..n)
            .map(|k| {
                let mut data = Vec::new();
                let mut keypoints = Vec::new();
                let seen: Vec<usize> = if closed {
                    vec![(k + n - 1) % n, k, (k + 1) % n]
                } else {
                    (k.saturating_sub(1)..=(k + 1).min(n - 1)).collect()
                };
                for p in seen {
                    for d in &places[p] {
                        let v: Vec<f32> =
                            d.iter().map(|x| x + 0.02 * rng.next_f64() as f32).collect();
                        let norm = v.iter().map(|x| x * x).sum::<f32>().sqrt();
                        data.extend(v.iter().map(|x| x / norm));
                        keypoints.push(Keypoint {
                            x: 0.0,
                            y: 0.0,
                            scale: 1.0,
                            orientation: 0.0,
                            response: rng.next_f64() as f32,
                        });
                    }
                }
                Features {
                    keypoints,
                    descriptors: Descriptors { dim, data },
                }
            })
            .collect()
    }

    fn opts() -> RetrievalOptions {
        RetrievalOptions {
            neighbours: 2,
            words: 16,
            training_descriptors: 5000,
            ..Default::default()
        }
    }

    #[test]
    fn neighbours_on_a_ring_are_found_in_any_order() {
        let n = 45;
        let features = ring(n, 3);
        let pairs = retrieval_pairs(&features, &opts()).expect("pairs");
        // Each image's two nearest places are its ring neighbours: the ring's edges, closure
        // (44, 0) included, are all there.
        for k in 0..n {
            let e = (k.min((k + 1) % n), k.max((k + 1) % n));
            assert!(pairs.contains(&e), "missing {e:?}");
        }
        // Shuffled files give the same pairs, relabelled.
        let perm: Vec<usize> = (0..n).map(|k| (k * 17 + 5) % n).collect();
        let mut shuffled = vec![features[0].clone(); n];
        for (k, &p) in perm.iter().enumerate() {
            shuffled[p] = features[k].clone();
        }
        let again = retrieval_pairs(&shuffled, &opts()).expect("pairs");
        let mut relabelled: Vec<(usize, usize)> = pairs
            .iter()
            .map(|&(a, b)| (perm[a].min(perm[b]), perm[a].max(perm[b])))
            .collect();
        relabelled.sort_unstable();
        let same = relabelled.iter().filter(|p| again.contains(p)).count();
        assert!(
            same as f64 >= 0.95 * relabelled.len() as f64,
            "{same} of {} pairs survive a shuffle",
            relabelled.len()
        );
    }

    #[test]
    fn bad_options_are_named() {
        let o = RetrievalOptions {
            neighbours: 0,
            ..Default::default()
        };
        assert!(matches!(
            o.validate(),
            Err(FeatureError::InvalidOption {
                option: "neighbours",
                ..
            })
        ));
    }

    #[test]
    fn a_shuffled_path_comes_back_in_its_order() {
        let n = 30;
        let features = scene(n, 4, false);
        let perm: Vec<usize> = (0..n).map(|k| (k * 7 + 3) % n).collect();
        let mut shuffled = vec![features[0].clone(); n];
        let mut original = vec![0; n];
        for (k, &p) in perm.iter().enumerate() {
            shuffled[p] = features[k].clone();
            original[p] = k;
        }
        let order = capture_order(&shuffled, &opts())
            .expect("ok")
            .expect("an order");
        let back: Vec<usize> = order.iter().map(|&p| original[p]).collect();
        let forward: Vec<usize> = (0..n).collect();
        let reversed: Vec<usize> = (0..n).rev().collect();
        assert!(back == forward || back == reversed, "{back:?}");
        // The pairs do not depend on the order of the files.
        let pairs = unordered_pairs(&features, 3, &opts()).expect("pairs");
        let again = unordered_pairs(&shuffled, 3, &opts()).expect("pairs");
        let mut relabelled: Vec<(usize, usize)> = again
            .iter()
            .map(|&(a, b)| (original[a].min(original[b]), original[a].max(original[b])))
            .collect();
        relabelled.sort_unstable();
        assert_eq!(pairs, relabelled);
        for k in 0..n - 1 {
            assert!(pairs.contains(&(k, k + 1)));
        }
    }
}
