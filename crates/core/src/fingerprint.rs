//! A fingerprint of values: FNV-1a (64 bits) over their bytes, stable across builds and
//! platforms (unlike `std`'s hasher), for telling whether a stored result was made from the
//! same inputs.

/// FNV-1a, fed value by value.
#[derive(Clone, Copy, Debug)]
pub struct Fingerprint(u64);

impl Default for Fingerprint {
    fn default() -> Self {
        Self(0xcbf2_9ce4_8422_2325)
    }
}

impl Fingerprint {
    pub fn bytes(&mut self, bytes: &[u8]) -> &mut Self {
        for byte in bytes {
            self.0 = (self.0 ^ u64::from(*byte)).wrapping_mul(0x0100_0000_01b3);
        }
        self
    }

    pub fn u64(&mut self, value: u64) -> &mut Self {
        self.bytes(&value.to_le_bytes())
    }

    /// Every bit of the value (so -0.0 and 0.0 differ, as do NaNs of different payloads).
    pub fn f64(&mut self, value: f64) -> &mut Self {
        self.u64(value.to_bits())
    }

    /// The string's bytes and its length (so "ab" + "c" differs from "a" + "bc").
    pub fn str(&mut self, value: &str) -> &mut Self {
        self.u64(value.len() as u64).bytes(value.as_bytes())
    }

    /// Sixteen hex digits.
    pub fn hex(&self) -> String {
        format!("{:016x}", self.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn known_value_and_boundaries() {
        // FNV-1a of "a" (the published test vector).
        assert_eq!(Fingerprint::default().bytes(b"a").hex(), "af63dc4c8601ec8c");
        let split = |a: &str, b: &str| Fingerprint::default().str(a).str(b).hex();
        assert_ne!(split("ab", "c"), split("a", "bc"));
        assert_ne!(Fingerprint::default().f64(0.0).hex(), Fingerprint::default().f64(-0.0).hex());
    }
}
