//! Anchoring learned keypoints to an image's own (SIFT) keypoints.
//!
//! COLMAP chains matches into tracks through shared keypoint indices. A
//! cross-visit match between two learned keypoints links two visits only if
//! one of its ends already belongs to a track of its own visit; anchoring a
//! learned keypoint to the own keypoint at the same spot (within a pixel or
//! two) makes that so, and lets COLMAP register one visit on the other's points.

use std::collections::HashMap;

use revisit_core::Keypoint;

/// For each point, the index of the nearest of `own` within `radius_px`, if any.
pub fn anchor_keypoints(own: &[Keypoint], points: &[[f32; 2]], radius_px: f32) -> Vec<Option<u32>> {
    if radius_px <= 0.0 || own.is_empty() {
        return vec![None; points.len()];
    }
    let cell = |x: f32, y: f32| ((x / radius_px).floor() as i64, (y / radius_px).floor() as i64);
    let mut grid: HashMap<(i64, i64), Vec<u32>> = HashMap::new();
    for (i, k) in own.iter().enumerate() {
        grid.entry(cell(k.x, k.y)).or_default().push(i as u32);
    }
    points
        .iter()
        .map(|&[x, y]| {
            let (cx, cy) = cell(x, y);
            let mut best: Option<(f32, u32)> = None;
            for dy in -1..=1 {
                for dx in -1..=1 {
                    for &i in grid.get(&(cx + dx, cy + dy)).into_iter().flatten() {
                        let k = &own[i as usize];
                        let d = (k.x - x).hypot(k.y - y);
                        if d <= radius_px && best.is_none_or(|(bd, bi)| (d, i) < (bd, bi)) {
                            best = Some((d, i));
                        }
                    }
                }
            }
            best.map(|(_, i)| i)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn anchors_to_the_nearest_within_the_radius() {
        let own =
            [(10.0, 10.0), (11.0, 10.0), (50.0, 50.0)].map(|(x, y)| Keypoint { x, y, scale: 1.0, orientation: 0.0 });
        let anchors = anchor_keypoints(&own, &[[10.9, 10.1], [52.5, 50.0], [10.2, 10.0]], 1.5);
        assert_eq!(anchors, vec![Some(1), None, Some(0)]);
    }
}
