//! Difference-of-Gaussian extrema and their sub-pixel, sub-scale refinement
//! (Lowe 2004, section 4; the same steps as OpenCV's `adjustLocalExtrema`).

use super::pyramid::Plane;

/// Pixels this close to an octave's border are never keypoints (OpenCV's
/// `SIFT_IMG_BORDER`): the refinement and the descriptor need a margin.
pub(crate) const BORDER_PX: usize = 5;
/// Newton steps of the quadratic fit before a candidate is given up.
const MAX_REFINE_STEPS: usize = 5;

/// A refined DoG extremum in one octave.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Extremum {
    /// Index of the octave in the pyramid (0 = first octave).
    pub octave: usize,
    /// Integer scale layer (1..=octave_resolution) whose Gaussian image the
    /// orientation and descriptor are computed on.
    pub layer: usize,
    /// Integer pixel the refinement converged at (octave pixels).
    pub column: usize,
    pub row: usize,
    /// Sub-pixel position, pixel centres at integers (octave pixels).
    pub x_octave: f32,
    pub y_octave: f32,
    /// Detection sigma in octave pixels.
    pub sigma_octave: f32,
    /// |DoG| at the refined extremum.
    pub response: f32,
}

/// Thresholds of the detector, in the units of images scaled to `[0, 1]`.
pub(crate) struct DetectParams {
    pub octave_resolution: usize,
    pub sigma: f32,
    /// Pixels with |DoG| at or below this are not extrema candidates.
    pub prelim_threshold: f32,
    /// Refined |DoG| below this is rejected.
    pub peak_threshold: f32,
    /// Ratio of principal curvatures above which an edge is rejected.
    pub edge_threshold: f32,
}

/// Finds and refines the extrema of the DoG layers `1..=octave_resolution` of
/// one octave (`dogs` holds `octave_resolution + 2` layers).
pub(crate) fn detect_octave(dogs: &[Plane], octave: usize, params: &DetectParams, out: &mut Vec<Extremum>) {
    let Some(first) = dogs.first() else {
        return;
    };
    let (width, height) = (first.width, first.height);
    if width <= 2 * BORDER_PX + 2 || height <= 2 * BORDER_PX + 2 {
        return;
    }
    let mut raw = Vec::new();
    for layer in 1..=params.octave_resolution {
        let (Some(below), Some(here), Some(above)) = (dogs.get(layer - 1), dogs.get(layer), dogs.get(layer + 1)) else {
            continue;
        };
        raw.clear();
        find_extrema(below, here, above, params.prelim_threshold, &mut raw);
        for &(column, row) in &raw {
            if let Some(extremum) = refine(dogs, octave, layer, column, row, params) {
                out.push(extremum);
            }
        }
    }
}

/// Strict local extrema over the 26 neighbours with |value| above `threshold`,
/// as (column, row), scanning rows then columns.
fn find_extrema(below: &Plane, here: &Plane, above: &Plane, threshold: f32, out: &mut Vec<(usize, usize)>) {
    let (width, height) = (here.width, here.height);
    for row in BORDER_PX..height - BORDER_PX {
        let rows = [
            below.row(row - 1),
            below.row(row),
            below.row(row + 1),
            here.row(row - 1),
            here.row(row),
            here.row(row + 1),
            above.row(row - 1),
            above.row(row),
            above.row(row + 1),
        ];
        let [b0, b1, b2, h0, h1, h2, a0, a1, a2] =
            rows.map(|r| r.get(BORDER_PX - 1..width - BORDER_PX + 1).unwrap_or(&[]));
        let centre = h1.array_windows::<3>();
        let neighbours = h0.array_windows::<3>().zip(h2.array_windows::<3>());
        let lower = b0.array_windows::<3>().zip(b1.array_windows::<3>()).zip(b2.array_windows::<3>());
        let upper = a0.array_windows::<3>().zip(a1.array_windows::<3>()).zip(a2.array_windows::<3>());
        for (offset, ((&[l, v, r], (up, down)), (lo, hi))) in centre.zip(neighbours).zip(lower.zip(upper)).enumerate() {
            let is_max = v > threshold && v > l && v > r;
            let is_min = v < -threshold && v < l && v < r;
            if !(is_max || is_min) {
                continue;
            }
            let ((lo0, lo1), lo2) = lo;
            let ((hi0, hi1), hi2) = hi;
            let others = [up, down, lo0, lo1, lo2, hi0, hi1, hi2];
            let extreme = if is_max {
                others.iter().all(|w| w.iter().all(|&n| v > n))
            } else {
                others.iter().all(|w| w.iter().all(|&n| v < n))
            };
            if extreme {
                out.push((BORDER_PX + offset, row));
            }
        }
    }
}

/// Gradient and Hessian of the DoG at (column, row, layer) by finite differences.
fn derivatives(dogs: &[Plane], layer: usize, c: usize, r: usize) -> Option<([f32; 3], [[f32; 3]; 3], f32)> {
    let (below, here, above) = (dogs.get(layer - 1)?, dogs.get(layer)?, dogs.get(layer + 1)?);
    let v = here.at(c, r);
    let dx = 0.5 * (here.at(c + 1, r) - here.at(c - 1, r));
    let dy = 0.5 * (here.at(c, r + 1) - here.at(c, r - 1));
    let ds = 0.5 * (above.at(c, r) - below.at(c, r));
    let dxx = here.at(c + 1, r) + here.at(c - 1, r) - 2.0 * v;
    let dyy = here.at(c, r + 1) + here.at(c, r - 1) - 2.0 * v;
    let dss = above.at(c, r) + below.at(c, r) - 2.0 * v;
    let dxy = 0.25 * (here.at(c + 1, r + 1) - here.at(c - 1, r + 1) - here.at(c + 1, r - 1) + here.at(c - 1, r - 1));
    let dxs = 0.25 * (above.at(c + 1, r) - above.at(c - 1, r) - below.at(c + 1, r) + below.at(c - 1, r));
    let dys = 0.25 * (above.at(c, r + 1) - above.at(c, r - 1) - below.at(c, r + 1) + below.at(c, r - 1));
    Some(([dx, dy, ds], [[dxx, dxy, dxs], [dxy, dyy, dys], [dxs, dys, dss]], v))
}

/// Solves `h x = b` for a symmetric 3x3 `h` by Cramer's rule; `None` when singular.
fn solve3(h: &[[f32; 3]; 3], b: [f32; 3]) -> Option<[f32; 3]> {
    let det3 = |m: &[[f32; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let det = det3(h);
    if !det.is_finite() || det.abs() < 1e-12 {
        return None;
    }
    let mut x = [0.0; 3];
    for (col, xi) in x.iter_mut().enumerate() {
        let mut m = *h;
        for (row, bi) in b.iter().enumerate() {
            m[row][col] = *bi;
        }
        *xi = det3(&m) / det;
    }
    Some(x)
}

/// Moves a candidate to the extremum of the quadratic fit of the DoG (at most
/// [`MAX_REFINE_STEPS`] pixel/layer moves), then applies the contrast and
/// edge tests.
fn refine(
    dogs: &[Plane],
    octave: usize,
    layer: usize,
    column: usize,
    row: usize,
    params: &DetectParams,
) -> Option<Extremum> {
    let here = dogs.get(layer)?;
    let (width, height) = (here.width, here.height);
    let (mut layer, mut c, mut r) = (layer, column, row);
    let mut converged = None;
    for _ in 0..MAX_REFINE_STEPS {
        let (gradient, hessian, value) = derivatives(dogs, layer, c, r)?;
        let step = solve3(&hessian, gradient)?;
        let offset = step.map(|s| -s);
        if offset.iter().all(|o| o.abs() < 0.5) {
            converged = Some((offset, gradient, hessian, value));
            break;
        }
        if offset.iter().any(|o| !o.is_finite() || o.abs() > 1e6) {
            return None;
        }
        let moved_c = c as f32 + offset[0].round();
        let moved_r = r as f32 + offset[1].round();
        let moved_layer = layer as f32 + offset[2].round();
        if moved_layer < 1.0
            || moved_layer > params.octave_resolution as f32
            || moved_c < BORDER_PX as f32
            || moved_c >= (width - BORDER_PX) as f32
            || moved_r < BORDER_PX as f32
            || moved_r >= (height - BORDER_PX) as f32
        {
            return None;
        }
        (c, r, layer) = (moved_c as usize, moved_r as usize, moved_layer as usize);
    }
    let (offset, gradient, hessian, value) = converged?;
    let contrast = value + 0.5 * (gradient[0] * offset[0] + gradient[1] * offset[1] + gradient[2] * offset[2]);
    if contrast.abs() < params.peak_threshold {
        return None;
    }
    let (dxx, dyy, dxy) = (hessian[0][0], hessian[1][1], hessian[0][1]);
    let trace = dxx + dyy;
    let det = dxx * dyy - dxy * dxy;
    let edge = params.edge_threshold;
    if det <= 0.0 || trace * trace * edge >= (edge + 1.0) * (edge + 1.0) * det {
        return None;
    }
    let scale_layer = layer as f32 + offset[2];
    Some(Extremum {
        octave,
        layer,
        column: c,
        row: r,
        x_octave: c as f32 + offset[0],
        y_octave: r as f32 + offset[1],
        sigma_octave: params.sigma * (scale_layer / params.octave_resolution as f32).exp2(),
        response: contrast.abs(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solve3_inverts_a_known_system() {
        let h = [[4.0, 1.0, 0.5], [1.0, 3.0, 0.25], [0.5, 0.25, 2.0]];
        let x = [0.3, -0.2, 0.7];
        let b = [0, 1, 2].map(|i| h[i][0] * x[0] + h[i][1] * x[1] + h[i][2] * x[2]);
        let got = solve3(&h, b).unwrap();
        for (g, e) in got.iter().zip(x) {
            assert!((g - e).abs() < 1e-5, "{got:?}");
        }
        assert!(solve3(&[[1.0, 2.0, 3.0], [2.0, 4.0, 6.0], [0.0, 0.0, 1.0]], [1.0, 1.0, 1.0]).is_none());
    }
}
