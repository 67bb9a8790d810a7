//! VLAD over learned local descriptors, with a k-means vocabulary.

use crate::{l2_normalise, GlobalDescriptor};

/// Cluster centres of local descriptors: `len()` centres of `dim` floats.
#[derive(Clone, Debug, PartialEq)]
pub struct Vocabulary {
    pub dim: usize,
    pub centres: Vec<f32>,
}

/// SplitMix64: a small, seeded generator for k-means++'s choices.
struct SplitMix(u64);

impl SplitMix {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
}

impl Vocabulary {
    /// k-means (k-means++ seeding, then `iterations` Lloyd steps) on `samples`,
    /// `dim` floats each. Deterministic for a given seed. Fewer samples than
    /// `k` give fewer centres.
    pub fn train(samples: &[f32], dim: usize, k: usize, iterations: usize, seed: u64) -> Vocabulary {
        let n = samples.len() / dim.max(1);
        let k = k.min(n);
        if k == 0 {
            return Vocabulary { dim, centres: Vec::new() };
        }
        let sample = |i: usize| &samples[i * dim..(i + 1) * dim];
        let mut random = SplitMix(seed);
        let mut centres: Vec<f32> = sample((random.next() % n as u64) as usize).to_vec();
        let mut nearest_sq: Vec<f32> = (0..n).map(|i| squared(sample(i), &centres[..dim])).collect();
        while centres.len() < k * dim {
            let total: f64 = nearest_sq.iter().map(|&d| f64::from(d)).sum();
            let mut target = random.unit() * total;
            let mut chosen = n - 1;
            for (i, &d) in nearest_sq.iter().enumerate() {
                target -= f64::from(d);
                if target < 0.0 {
                    chosen = i;
                    break;
                }
            }
            let start = centres.len();
            centres.extend_from_slice(sample(chosen));
            for (i, d) in nearest_sq.iter_mut().enumerate() {
                *d = d.min(squared(sample(i), &centres[start..start + dim]));
            }
        }
        let mut vocabulary = Vocabulary { dim, centres };
        for _ in 0..iterations {
            let mut sums = vec![0.0f64; k * dim];
            let mut counts = vec![0usize; k];
            for i in 0..n {
                let c = vocabulary.assign(sample(i));
                counts[c] += 1;
                for (s, &v) in sums[c * dim..(c + 1) * dim].iter_mut().zip(sample(i)) {
                    *s += f64::from(v);
                }
            }
            for c in 0..k {
                if counts[c] > 0 {
                    for d in 0..dim {
                        vocabulary.centres[c * dim + d] = (sums[c * dim + d] / counts[c] as f64) as f32;
                    }
                }
            }
        }
        vocabulary
    }

    pub fn len(&self) -> usize {
        self.centres.len() / self.dim.max(1)
    }

    pub fn is_empty(&self) -> bool {
        self.centres.is_empty()
    }

    /// The nearest centre of `descriptor`.
    pub fn assign(&self, descriptor: &[f32]) -> usize {
        (0..self.len())
            .map(|c| (c, squared(descriptor, &self.centres[c * self.dim..(c + 1) * self.dim])))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map_or(0, |(c, _)| c)
    }
}

fn squared(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum()
}

/// VLAD with signed square-root and intra-normalisation (Arandjelović and
/// Zisserman, 2013): `len(vocabulary) * dim` floats, L2-normalised.
#[derive(Clone, Debug, PartialEq)]
pub struct Vlad {
    pub vocabulary: Vocabulary,
    /// Identifies the local features the vocabulary was learned on.
    pub features: String,
}

impl GlobalDescriptor for Vlad {
    fn name(&self) -> String {
        format!("vlad{}-{}", self.vocabulary.len(), self.features)
    }
}

impl Vlad {
    /// The VLAD vector of one image's local descriptors (`dim` floats each).
    pub fn describe(&self, descriptors: &[f32]) -> Vec<f32> {
        let dim = self.vocabulary.dim;
        let mut vlad = vec![0.0f32; self.vocabulary.len() * dim];
        for descriptor in descriptors.chunks_exact(dim) {
            let c = self.vocabulary.assign(descriptor);
            let centre = &self.vocabulary.centres[c * dim..(c + 1) * dim];
            for ((v, x), m) in vlad[c * dim..(c + 1) * dim].iter_mut().zip(descriptor).zip(centre) {
                *v += x - m;
            }
        }
        for v in &mut vlad {
            *v = v.signum() * v.abs().sqrt();
        }
        for block in vlad.chunks_exact_mut(dim) {
            l2_normalise(block);
        }
        l2_normalise(&mut vlad);
        vlad
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Points around three well-separated centres in 2-D.
    fn blobs() -> Vec<f32> {
        let centres = [[0.0, 0.0], [10.0, 0.0], [0.0, 10.0]];
        let mut random = SplitMix(7);
        let mut out = Vec::new();
        for i in 0..300 {
            let c = centres[i % 3];
            out.push(c[0] + random.unit() as f32 - 0.5);
            out.push(c[1] + random.unit() as f32 - 0.5);
        }
        out
    }

    #[test]
    fn k_means_finds_separated_clusters_deterministically() {
        let samples = blobs();
        let vocabulary = Vocabulary::train(&samples, 2, 3, 10, 1);
        assert_eq!(vocabulary, Vocabulary::train(&samples, 2, 3, 10, 1));
        let mut found: Vec<(i32, i32)> =
            vocabulary.centres.chunks_exact(2).map(|c| (c[0].round() as i32, c[1].round() as i32)).collect();
        found.sort_unstable();
        assert_eq!(found, vec![(0, 0), (0, 10), (10, 0)]);
    }

    #[test]
    fn vlad_is_normalised_and_tells_images_apart() {
        let samples = blobs();
        let vlad = Vlad { vocabulary: Vocabulary::train(&samples, 2, 3, 10, 1), features: "test".into() };
        let a = vlad.describe(&samples[..200]);
        let a_again = vlad.describe(&samples[100..300]);
        let b = vlad.describe(&[9.0, 0.5, 10.5, -0.2, 0.3, 9.1]);
        let norm: f32 = a.iter().map(|v| v * v).sum::<f32>().sqrt();
        assert!((norm - 1.0).abs() < 1e-5);
        let distance = |x: &[f32], y: &[f32]| x.iter().zip(y).map(|(p, q)| (p - q).powi(2)).sum::<f32>().sqrt();
        assert!(distance(&a, &a_again) < distance(&a, &b));
    }
}
