//! Point-cloud registration with Open3D, in the project's Python: the script
//! is embedded in the binary and written next to the clouds it reads.

use std::path::Path;
use std::process::Command;
use std::sync::atomic::AtomicBool;

use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};
use revisit_colmap::{run_until_cancelled, write_ply, PlyColors};
use revisit_core::{Reconstruction, Similarity};
use serde::Deserialize;

use crate::PosthocError;

/// The registration script (Open3D), as embedded.
const REGISTER_SCRIPT: &str = include_str!("../python/revisit_register.py");

/// Which registration the script runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Registration {
    /// Point-to-point ICP with scale from the centroids and spreads.
    Icp,
    /// FPFH + RANSAC global registration, then ICP.
    Fpfh,
}

/// What a registration found.
#[derive(Clone, Debug, PartialEq)]
pub enum Registered {
    Aligned {
        fixed_from_moving: Similarity,
        fitness: f64,
    },
    /// It found nothing (too few points, no consistent matches, no overlap).
    Failed {
        reason: String,
    },
}

#[derive(Deserialize)]
struct ScriptResult {
    ok: bool,
    reason: Option<String>,
    fixed_from_moving: Option<[[f64; 4]; 4]>,
    fitness: Option<f64>,
}

/// Registers `moving`'s points onto `fixed`'s; `scratch` (created) holds the
/// two clouds and the script.
pub fn register(
    python: &Path,
    scratch: &Path,
    fixed: &Reconstruction,
    moving: &Reconstruction,
    method: Registration,
    seed: u64,
    cancelled: &AtomicBool,
) -> Result<Registered, PosthocError> {
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |source| PosthocError::Io { path, source }
    };
    std::fs::create_dir_all(scratch).map_err(io(scratch))?;
    let (script, fixed_ply, moving_ply) =
        (scratch.join("revisit_register.py"), scratch.join("fixed.ply"), scratch.join("moving.ply"));
    std::fs::write(&script, REGISTER_SCRIPT).map_err(io(&script))?;
    write_ply(fixed, &fixed_ply, PlyColors::Rgb)?;
    write_ply(moving, &moving_ply, PlyColors::Rgb)?;
    let mut command = Command::new(python);
    command
        .arg(&script)
        .arg("--fixed")
        .arg(&fixed_ply)
        .arg("--moving")
        .arg(&moving_ply)
        .args(["--method", if method == Registration::Icp { "icp" } else { "fpfh" }])
        .args(["--seed", &seed.to_string()])
        // Open3D's RANSAC draws per thread: one thread keeps a seed's result.
        .env("OMP_NUM_THREADS", "1");
    let output = run_until_cancelled(command, cancelled)
        .map_err(|source| PosthocError::Spawn { python: python.to_path_buf(), source })?
        .ok_or(PosthocError::Cancelled)?;
    if !output.status.success() {
        let stderr = String::from_utf8_lossy(&output.stderr);
        let tail: Vec<&str> = stderr.lines().rev().take(5).collect();
        return Err(PosthocError::Failed {
            status: output.status.to_string(),
            stderr_tail: tail.into_iter().rev().collect::<Vec<_>>().join(" | "),
        });
    }
    let stdout = String::from_utf8_lossy(&output.stdout);
    let line = stdout.lines().last().unwrap_or_default();
    let result: ScriptResult =
        serde_json::from_str(line).map_err(|e| PosthocError::BadResult(format!("{e}: {line}")))?;
    match (result.ok, result.fixed_from_moving, result.fitness) {
        (true, Some(matrix), Some(fitness)) => match similarity_of(&matrix) {
            Some(fixed_from_moving) => Ok(Registered::Aligned { fixed_from_moving, fitness }),
            None => Ok(Registered::Failed { reason: "the registration's transform is not a similarity".to_owned() }),
        },
        _ => Ok(Registered::Failed { reason: result.reason.unwrap_or_else(|| "no reason given".to_owned()) }),
    }
}

/// The similarity of a 4x4 matrix `[s R | t]`, if it is one.
fn similarity_of(m: &[[f64; 4]; 4]) -> Option<Similarity> {
    let linear = Matrix3::from_fn(|r, c| m[r][c]);
    let determinant = linear.determinant();
    if !determinant.is_finite() || determinant <= 0.0 {
        return None;
    }
    let scale = determinant.cbrt();
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix(&(linear / scale)));
    let translation = Vector3::new(m[0][3], m[1][3], m[2][3]);
    Some(Similarity { scale, rotation, translation })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_scaled_rotation_reads_back() {
        let rotation = UnitQuaternion::from_euler_angles(0.3, -0.2, 1.1);
        let linear = rotation.to_rotation_matrix().matrix() * 2.5;
        let mut m = [[0.0; 4]; 4];
        for (r, row) in m.iter_mut().enumerate().take(3) {
            for (c, cell) in row.iter_mut().enumerate().take(3) {
                *cell = linear[(r, c)];
            }
            row[3] = [1.0, -2.0, 3.0][r];
        }
        m[3][3] = 1.0;
        let s = similarity_of(&m).unwrap();
        assert!((s.scale - 2.5).abs() < 1e-12 && s.rotation.angle_to(&rotation) < 1e-9);
        assert_eq!(s.translation, Vector3::new(1.0, -2.0, 3.0));
        m[0][0] = -m[0][0];
        m[1][0] = -m[1][0];
        m[2][0] = -m[2][0];
        assert_eq!(similarity_of(&m), None, "a reflection is not a similarity");
    }
}
