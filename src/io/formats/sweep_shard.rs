//! The manifest of one shard of a sweep (`flatport sweep --shard I/N`): `DIR/shard.json`, beside
//! the shard's `cost.npy` (and `distance.npy` for a profile), one-dimensional over the shard's
//! cells. `flatport sweep merge` reads the manifests to check that the shards belong together
//! (same cost, grid, inputs) and cover the grid once.
//!
//! ```json
//! {"format": "flatport sweep shard", "version": 1,
//!  "shard": {"index": 0, "count": 4}, "cells": {"start": 0, "end": 1024, "total": 4096},
//!  "cost": "affine-grid",
//!  "grid": {"tilt_deg": {"start": 0, "stop": 20, "count": 64}, "azimuth_deg": {…}, "distance": null},
//!  "inputs": {"rig_sha256": "…", "observations_sha256": "…", "correspondences": 9990, "views": 185},
//!  "device": "cpu (f64 reference, 2 threads)", "seconds": 1.25, "finite_cells": 1024}
//! ```

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::rig_json::parse_json;
use crate::io::error::{EXCERPT_CHARS, excerpt};
use crate::io::{IoError, read_text, write_atomic};

/// `format` of every manifest.
pub const SHARD_FORMAT: &str = "flatport sweep shard";
/// `version` of the manifests written here.
pub const SHARD_VERSION: u32 = 1;

/// One shard's manifest.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShardManifest {
    /// [`SHARD_FORMAT`].
    pub format: String,
    /// [`SHARD_VERSION`].
    pub version: u32,
    /// Which slice.
    pub shard: ShardIndex,
    /// The slice's cells in the whole grid, row-major.
    pub cells: CellRange,
    /// The cost's name (`CostKind::name`).
    pub cost: String,
    /// The grid.
    pub grid: GridAxes,
    /// What the sweep read.
    pub inputs: ShardInputs,
    /// The device that evaluated the slice.
    pub device: String,
    /// Wall-clock seconds of the slice.
    pub seconds: f64,
    /// Cells of the slice with a finite cost.
    pub finite_cells: usize,
}

/// `shard`: INDEX/COUNT.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShardIndex {
    /// 0-based.
    pub index: usize,
    /// Shards in all.
    pub count: usize,
}

/// `cells`: start..end of total.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CellRange {
    /// First cell.
    pub start: usize,
    /// One past the last cell.
    pub end: usize,
    /// Cells of the whole grid.
    pub total: usize,
}

/// `grid`: the three axes as START:STOP:COUNT.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GridAxes {
    /// Tilts, degrees.
    pub tilt_deg: GridAxis,
    /// Azimuths, degrees.
    pub azimuth_deg: GridAxis,
    /// Air layers, metres; `null` for a profile.
    pub distance: Option<GridAxis>,
}

/// One axis of the grid (numpy's `linspace(start, stop, count)`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GridAxis {
    /// First value.
    pub start: f64,
    /// Last value.
    pub stop: f64,
    /// Number of values.
    pub count: usize,
}

/// `inputs`: what the cost was evaluated on.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShardInputs {
    /// SHA-256 of the rig file's bytes, hex.
    pub rig_sha256: String,
    /// SHA-256 of the observations file's bytes, hex.
    pub observations_sha256: String,
    /// Correspondences (corners seen by both cameras).
    pub correspondences: usize,
    /// Views.
    pub views: usize,
}

/// SHA-256 of a file's bytes, lower-case hex.
pub fn sha256_file(path: &Path) -> Result<String, IoError> {
    use sha2::Digest;
    let mut file = std::fs::File::open(path).map_err(|source| IoError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    let mut hasher = sha2::Sha256::new();
    std::io::copy(&mut file, &mut hasher).map_err(|source| IoError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    Ok(hasher
        .finalize()
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect())
}

/// Writes `manifest` to `path` (JSON, whole or not at all).
pub fn write_shard_manifest(path: &Path, manifest: &ShardManifest) -> Result<(), IoError> {
    let mut text = serde_json::to_string_pretty(manifest).expect("plain data");
    text.push('\n');
    write_atomic(path, text.as_bytes())
}

/// Reads a manifest.
///
/// Errors: [`IoError::Read`] when it cannot be read; [`IoError::Json`] or [`IoError::Invalid`]
/// naming the file and JSON path when it is not a shard manifest of this version, or its cells do
/// not lie in the grid.
pub fn read_shard_manifest(path: &Path) -> Result<ShardManifest, IoError> {
    let manifest: ShardManifest = parse_json(&read_text(path)?, path)?;
    let invalid = |field: &str, reason: String| IoError::Invalid {
        path: path.to_path_buf(),
        field: field.into(),
        reason,
    };
    if manifest.format != SHARD_FORMAT {
        return Err(invalid(
            "format",
            format!(
                "'{}' is not '{SHARD_FORMAT}'",
                excerpt(&manifest.format, EXCERPT_CHARS)
            ),
        ));
    }
    if manifest.version != SHARD_VERSION {
        return Err(invalid(
            "version",
            format!(
                "version {} is not {SHARD_VERSION}, the one this flatport reads",
                manifest.version
            ),
        ));
    }
    let (shard, cells) = (manifest.shard, manifest.cells);
    if shard.count == 0 || shard.index >= shard.count {
        return Err(invalid(
            "shard",
            format!("index {} is not below count {}", shard.index, shard.count),
        ));
    }
    if cells.start > cells.end || cells.end > cells.total {
        return Err(invalid(
            "cells",
            format!(
                "{}..{} is not within the grid's {} cells",
                cells.start, cells.end, cells.total
            ),
        ));
    }
    Ok(manifest)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn manifest() -> ShardManifest {
        let axis = GridAxis {
            start: 0.0,
            stop: 20.0,
            count: 8,
        };
        ShardManifest {
            format: SHARD_FORMAT.into(),
            version: SHARD_VERSION,
            shard: ShardIndex { index: 1, count: 4 },
            cells: CellRange {
                start: 16,
                end: 32,
                total: 64,
            },
            cost: "affine-grid".into(),
            grid: GridAxes {
                tilt_deg: axis,
                azimuth_deg: GridAxis {
                    start: -180.0,
                    stop: 180.0,
                    count: 8,
                },
                distance: None,
            },
            inputs: ShardInputs {
                rig_sha256: "ab".into(),
                observations_sha256: "cd".into(),
                correspondences: 10,
                views: 3,
            },
            device: "cpu".into(),
            seconds: 0.5,
            finite_cells: 16,
        }
    }

    #[test]
    fn manifests_round_trip_and_bad_ones_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("shard.json");
        let mut m = manifest();
        m.grid.tilt_deg.stop = 0.1 + 0.2; // round-trips exactly
        write_shard_manifest(&path, &m).unwrap();
        assert_eq!(read_shard_manifest(&path).unwrap(), m);
        let text = std::fs::read_to_string(&path).unwrap();
        for (from, to, field) in [
            ("\"version\": 1", "\"version\": 2", "version"),
            ("\"index\": 1", "\"index\": 4", "shard"),
            ("\"end\": 32", "\"end\": 65", "cells"),
            (
                "\"format\": \"flatport sweep shard\"",
                "\"format\": \"other\"",
                "format",
            ),
            ("\"seconds\"", "\"second\"", "second"),
        ] {
            std::fs::write(&path, text.replace(from, to)).unwrap();
            let error = read_shard_manifest(&path).unwrap_err().to_string();
            assert!(
                error.contains("shard.json") && error.contains(field),
                "{from}: {error}"
            );
        }
    }

    #[test]
    fn sha256_of_a_file_is_the_standard_one() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("abc");
        std::fs::write(&path, "abc").unwrap();
        // FIPS 180-2, appendix B.1.
        assert_eq!(
            sha256_file(&path).unwrap(),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
    }
}
