//! COLMAP's blobs: little-endian, row-major arrays.

pub fn f32s(values: &[f32]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

pub fn f64s(values: &[f64]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

pub fn u32s(values: &[u32]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

/// A 3x3 matrix as 9 row-major f64s, as COLMAP stores F, E and H.
pub fn matrix_row_major(m: &nalgebra::Matrix3<f64>) -> Vec<u8> {
    f64s(m.transpose().as_slice())
}

fn decode<const N: usize, T>(bytes: &[u8], from: impl Fn([u8; N]) -> T) -> Option<Vec<T>> {
    if !bytes.len().is_multiple_of(N) {
        return None;
    }
    bytes.chunks_exact(N).map(|c| c.try_into().ok().map(&from)).collect()
}

pub fn to_f32s(bytes: &[u8]) -> Option<Vec<f32>> {
    decode(bytes, f32::from_le_bytes)
}

pub fn to_f64s(bytes: &[u8]) -> Option<Vec<f64>> {
    decode(bytes, f64::from_le_bytes)
}

pub fn to_u32s(bytes: &[u8]) -> Option<Vec<u32>> {
    decode(bytes, u32::from_le_bytes)
}
