//! Deterministic, hash-based procedural noise (gradient noise, fractal sums,
//! cellular patterns) and a small seeded random number generator.
//!
//! Everything here is a pure function of its inputs and seed, so the scene is
//! the same on every machine and thread count.

/// A 32-bit integer hash of a lattice point and a seed (lowbias32 finaliser).
#[inline]
pub fn hash2(x: i32, y: i32, seed: u32) -> u32 {
    let mut h = seed.wrapping_mul(0x9E37_79B9)
        ^ (x as u32).wrapping_mul(0x85EB_CA6B)
        ^ (y as u32).wrapping_mul(0xC2B2_AE35).rotate_left(13);
    h ^= h >> 16;
    h = h.wrapping_mul(0x7FEB_352D);
    h ^= h >> 15;
    h = h.wrapping_mul(0x846C_A68B);
    h ^= h >> 16;
    h
}

/// Mixes two values into a new seed.
#[inline]
pub fn mix(a: u32, b: u32) -> u32 {
    hash2(a as i32, b as i32, 0x5EED_1234)
}

/// The top 24 bits of a hash as a float in [0, 1).
#[inline]
pub fn unit(h: u32) -> f32 {
    (h >> 8) as f32 * (1.0 / 16_777_216.0)
}

#[inline(always)]
fn quintic(t: f32) -> f32 {
    t * t * t * (t * (t * 6.0 - 15.0) + 10.0)
}

#[inline(always)]
fn lattice_gradient(ix: i32, iy: i32, seed: u32, dx: f32, dy: f32) -> f32 {
    let h = hash2(ix, iy, seed);
    let gx = (h & 0xFFFF) as f32 * (2.0 / 65535.0) - 1.0;
    let gy = (h >> 16) as f32 * (2.0 / 65535.0) - 1.0;
    gx * dx + gy * dy
}

/// Gradient (Perlin-style) noise, roughly in [-1, 1], zero at lattice points.
/// `floor` without a libm call (the baseline x86-64 target has no SSE4.1 round).
#[inline(always)]
fn floor_i32(x: f32) -> i32 {
    let i = x as i32;
    if (i as f32) > x {
        i - 1
    } else {
        i
    }
}

#[inline(always)]
pub fn gradient(x: f32, y: f32, seed: u32) -> f32 {
    let (ix, iy) = (floor_i32(x), floor_i32(y));
    let (xf, yf) = (ix as f32, iy as f32);
    let (fx, fy) = (x - xf, y - yf);
    let n00 = lattice_gradient(ix, iy, seed, fx, fy);
    let n10 = lattice_gradient(ix + 1, iy, seed, fx - 1.0, fy);
    let n01 = lattice_gradient(ix, iy + 1, seed, fx, fy - 1.0);
    let n11 = lattice_gradient(ix + 1, iy + 1, seed, fx - 1.0, fy - 1.0);
    let (u, v) = (quintic(fx), quintic(fy));
    let a = n00 + (n10 - n00) * u;
    let b = n01 + (n11 - n01) * u;
    1.6 * (a + (b - a) * v)
}

/// Fractal sum of gradient noise. Each octave doubles the frequency and rotates
/// the domain by about 37 degrees so that no lattice direction dominates.
pub fn fbm(x: f32, y: f32, octaves: u32, gain: f32, seed: u32) -> f32 {
    let (mut x, mut y) = (x, y);
    let mut sum = 0.0;
    let mut amp = 1.0;
    let mut norm = 0.0;
    for octave in 0..octaves {
        sum += amp * gradient(x, y, seed.wrapping_add(octave.wrapping_mul(101)));
        norm += amp;
        amp *= gain;
        let nx = 1.6 * x - 1.2 * y + 17.31;
        let ny = 1.2 * x + 1.6 * y - 5.17;
        x = nx;
        y = ny;
    }
    if norm > 0.0 {
        sum / norm
    } else {
        0.0
    }
}

/// Ridged fractal noise in [0, 1]: thin bright ridges where the noise crosses zero.
pub fn ridged(x: f32, y: f32, octaves: u32, seed: u32) -> f32 {
    let (mut x, mut y) = (x, y);
    let mut sum = 0.0;
    let mut amp = 1.0;
    let mut norm = 0.0;
    for octave in 0..octaves {
        let n = 1.0 - gradient(x, y, seed.wrapping_add(octave.wrapping_mul(131))).abs();
        sum += amp * n * n;
        norm += amp;
        amp *= 0.5;
        let nx = 1.6 * x - 1.2 * y + 3.7;
        let ny = 1.2 * x + 1.6 * y + 11.9;
        x = nx;
        y = ny;
    }
    if norm > 0.0 {
        sum / norm
    } else {
        0.0
    }
}

/// Cellular (Worley) noise: distances to the nearest and second-nearest
/// feature point (in cell units) and the hash of the nearest cell.
#[derive(Clone, Copy, Debug)]
pub struct Cell {
    pub f1: f32,
    pub f2: f32,
    pub id: u32,
}

pub fn cellular(x: f32, y: f32, seed: u32) -> Cell {
    let (ix, iy) = (floor_i32(x), floor_i32(y));
    let (xf, yf) = (ix as f32, iy as f32);
    let (fx, fy) = (x - xf, y - yf);
    let mut f1 = f32::MAX;
    let mut f2 = f32::MAX;
    let mut id = 0;
    for dy in -1..=1 {
        for dx in -1..=1 {
            let h = hash2(ix + dx, iy + dy, seed);
            let px = dx as f32 + 0.1 + 0.8 * unit(h) - fx;
            let py = dy as f32 + 0.1 + 0.8 * unit(h.wrapping_mul(0x2C1B_3C6D) ^ 0x1234_5678) - fy;
            let d = px * px + py * py;
            if d < f1 {
                f2 = f1;
                f1 = d;
                id = h;
            } else if d < f2 {
                f2 = d;
            }
        }
    }
    Cell { f1: f1.sqrt(), f2: f2.sqrt(), id }
}

#[inline]
pub fn smoothstep(edge0: f32, edge1: f32, x: f32) -> f32 {
    let t = ((x - edge0) / (edge1 - edge0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

#[inline]
pub fn lerp3(a: [f32; 3], b: [f32; 3], t: f32) -> [f32; 3] {
    [a[0] + (b[0] - a[0]) * t, a[1] + (b[1] - a[1]) * t, a[2] + (b[2] - a[2]) * t]
}

#[inline]
pub fn scale3(a: [f32; 3], s: f32) -> [f32; 3] {
    [a[0] * s, a[1] * s, a[2] * s]
}

/// SplitMix64: a tiny, fast, well-mixed generator. Its output sequence is fixed
/// forever, which keeps surveys byte-identical across dependency upgrades.
#[derive(Clone, Debug)]
pub struct SplitMix64(u64);

impl SplitMix64 {
    pub fn new(seed: u64) -> Self {
        Self(seed ^ 0x6A09_E667_F3BC_C909)
    }

    /// A generator for a named sub-stream of `seed` (scene, session, image...).
    pub fn stream(seed: u64, stream: u64) -> Self {
        let mut g = Self::new(seed);
        let a = g.next_u64();
        Self::new(a ^ stream.wrapping_mul(0x9E37_79B9_7F4A_7C15))
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    pub fn next_u32(&mut self) -> u32 {
        (self.next_u64() >> 32) as u32
    }

    /// Uniform in [0, 1).
    pub fn f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / 9_007_199_254_740_992.0)
    }

    /// Uniform in [lo, hi).
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.f64()
    }

    /// True with probability `p`.
    pub fn chance(&mut self, p: f64) -> bool {
        self.f64() < p
    }

    /// Standard normal (Box-Muller).
    pub fn normal(&mut self) -> f64 {
        let u1 = self.f64().max(1e-300);
        let u2 = self.f64();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }

    /// Uniform integer in [0, n) (0 when n is 0).
    pub fn below(&mut self, n: usize) -> usize {
        if n == 0 {
            0
        } else {
            (self.f64() * n as f64) as usize % n
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noise_is_bounded_and_varied() {
        let mut lo = f32::MAX;
        let mut hi = f32::MIN;
        for i in 0..10_000 {
            let v = fbm(i as f32 * 0.173, i as f32 * 0.071, 5, 0.5, 7);
            lo = lo.min(v);
            hi = hi.max(v);
        }
        assert!(lo > -1.5 && hi < 1.5 && hi - lo > 0.8, "{lo} {hi}");
    }

    #[test]
    fn rng_is_deterministic() {
        let a: Vec<u64> = (0..4)
            .map({
                let mut g = SplitMix64::new(3);
                move |_| g.next_u64()
            })
            .collect();
        let mut g = SplitMix64::new(3);
        assert_eq!(a, (0..4).map(|_| g.next_u64()).collect::<Vec<_>>());
    }
}
