//! Drawing minimal samples. The sampler owns its random generator, seeded explicitly, so a run is a
//! pure function of its inputs and seed (STYLE.md: no hidden thread-local generator).

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// Draws index sets for minimal samples and owns the generator used by the whole run (the T(d,d)
/// test draws its check points from [`Sampler::rng`] too).
pub trait Sampler {
    /// Replaces the content of `out` with `k` distinct indices in `0..n` (`k ≤ n`).
    fn sample(&mut self, n: usize, k: usize, out: &mut Vec<usize>);

    /// The generator, for other random choices of the run.
    fn rng(&mut self) -> &mut ChaCha8Rng;
}

/// Uniform sampling without replacement (Fischler & Bolles 1981).
#[derive(Clone, Debug)]
pub struct UniformSampler {
    rng: ChaCha8Rng,
}

impl UniformSampler {
    /// A sampler whose draws are fully determined by `seed`.
    pub fn new(seed: u64) -> Self {
        Self {
            rng: ChaCha8Rng::seed_from_u64(seed),
        }
    }
}

impl Sampler for UniformSampler {
    fn sample(&mut self, n: usize, k: usize, out: &mut Vec<usize>) {
        out.clear();
        let k = k.min(n);
        out.extend(rand::seq::index::sample(&mut self.rng, n, k).iter());
    }

    fn rng(&mut self) -> &mut ChaCha8Rng {
        &mut self.rng
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_are_distinct_in_range_and_reproducible() {
        let (mut a, mut b) = (UniformSampler::new(5), UniformSampler::new(5));
        let (mut sa, mut sb) = (Vec::new(), Vec::new());
        for _ in 0..100 {
            a.sample(20, 7, &mut sa);
            b.sample(20, 7, &mut sb);
            assert_eq!(sa, sb);
            assert_eq!(sa.len(), 7);
            let mut s = sa.clone();
            s.sort_unstable();
            s.dedup();
            assert_eq!(s.len(), 7);
            assert!(sa.iter().all(|&i| i < 20));
        }
        a.sample(3, 7, &mut sa);
        assert_eq!(sa.len(), 3);
    }
}
