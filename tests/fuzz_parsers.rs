//! Fuzzing every parser (issue 14): random bytes and random mutations of valid rig, observations,
//! truth, OpenCV YAML, CSV and `.npy` inputs. Each parser must return `Ok` or an error, never
//! panic (proptest turns a panic into a failing, shrunk case). Case counts are bounded so the file
//! runs in seconds in release; raise `FUZZ_CASES` locally for a longer campaign
//! (`FUZZ_CASES=100000 cargo test --release --test fuzz_parsers`).

use std::path::Path;

use flatport::io::npy::npy_from_bytes;
use flatport::io::{
    TableReader, observations_from_json_str, parse_opencv_stereo, read_observations, read_rig,
    read_table_from, read_truth, rig_from_json_str,
};
use proptest::prelude::*;

const RIG: &str = include_str!("../data/example_rig.json");

/// A small valid observations file: a 3 × 2 board seen in two views, one corner missing.
const OBSERVATIONS: &str = r#"{"board": {"rows": 2, "cols": 3, "square": 0.04}, "cameras": ["left", "right"],
 "views": [
  {"left": [[600.5, 480.25], [640, 480], [680, 480], [600, 520], [640, 520], [680, 520]],
   "right": [[560, 481], [600, 481], [640, 481], [560, 521], null, [640, 521]]},
  {"left": [[500, 400], [540, 401], [580, 402], [500, 440], [540, 441], [580, 442]],
   "right": [[460, 400], [500, 401], [540, 402], [460, 440], [500, 441], [540, 442]]}
 ]}
"#;

/// A truth file as `flatport simulate` writes it.
const TRUTH: &str = r#"{
  "interface": {"normal": [0.1, 0.1, 1.0], "distance": 0.02, "layers": [{"thickness": 0.014, "index": 1.473}],
                "index_air": 1.003, "index_water": 1.333},
  "tilt_deg": 8.0, "azimuth_deg": 45.0, "noise_px": 0.1, "seed": 1,
  "board_poses": [{"rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "translation": [0, 0, 1.2]}]
}
"#;

/// What `cv::FileStorage` writes for a stereo calibration.
const YAML: &str = "%YAML:1.0
---
image_width: 1280
image_height: 1024
M1: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 8.6491000000000003e+02, 0., 640., 0., 8.6491000000000003e+02,
       512., 0., 0., 1. ]
D1: !!opencv-matrix
   rows: 1
   cols: 5
   dt: d
   data: [ -1.0e-01, 1.0e-02, .5e-3, -2.5e-03, 0. ]
M2: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 870., 0., 630., 0., 870., 500., 0., 0., 1. ]
D2: !!opencv-matrix
   rows: 1
   cols: 5
   dt: d
   data: [ -0.09, 0.011, 0., 0., 0. ]
R: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 9.9984769515639127e-01, 0., 1.7452406437283512e-02, 0., 1.,
       0., -1.7452406437283512e-02, 0., 9.9984769515639127e-01 ]
T: !!opencv-matrix
   rows: 3
   cols: 1
   dt: d
   data: [ -6.0e-02, 0., 0. ]
per_view_errors: [ 0.21, 0.19,
    0.30, 0.18 ]
";

const CSV: &str = "x,y,z\n0.1,0.2,1\n\n-0.3, 0.25 ,2.5e0\n\"1\",2,3\r\n4,5,6";

/// Tokens that the formats give meaning to, spliced in by the mutations.
const TOKENS: &[&str] = &[
    "null",
    "[",
    "]",
    "{",
    "}",
    "\"",
    ",",
    ":",
    "-",
    "1e999",
    "-0",
    "NaN",
    "inf",
    ".Nan",
    "\u{feff}",
    "\n",
    "\r\n",
    " ",
    "\t",
    "#",
    "%YAML:1.0",
    "---",
    "!!opencv-matrix",
    "rows: 3",
    "dt: d",
    "data: [",
    "\"cameras\": [",
    "\"translation\":",
    "18446744073709551615",
    "99999999999999999999999",
    "0.",
    "\\u0000",
    "\u{ff}",
    "é",
    "'shape': (",
    "'descr': '<f8'",
];

/// One edit of a byte string; positions are fractions of its length, so they apply to any input.
#[derive(Debug, Clone)]
enum Mutation {
    Flip { at: f64, bit: u8 },
    Insert { at: f64, byte: u8 },
    Delete { at: f64, len: usize },
    Token { at: f64, token: usize },
    Duplicate { from: f64, len: usize, to: f64 },
    Truncate { at: f64 },
}

fn mutation() -> impl Strategy<Value = Mutation> {
    let at = 0.0..=1.0f64;
    prop_oneof![
        (at.clone(), 0u8..8).prop_map(|(at, bit)| Mutation::Flip { at, bit }),
        (at.clone(), any::<u8>()).prop_map(|(at, byte)| Mutation::Insert { at, byte }),
        (at.clone(), 1usize..16).prop_map(|(at, len)| Mutation::Delete { at, len }),
        (at.clone(), 0..TOKENS.len()).prop_map(|(at, token)| Mutation::Token { at, token }),
        (at.clone(), 1usize..64, at.clone()).prop_map(|(from, len, to)| Mutation::Duplicate {
            from,
            len,
            to
        }),
        at.prop_map(|at| Mutation::Truncate { at }),
    ]
}

fn index(at: f64, len: usize) -> usize {
    ((at * len as f64) as usize).min(len)
}

fn mutate(seed: &[u8], mutations: &[Mutation]) -> Vec<u8> {
    let mut bytes = seed.to_vec();
    for m in mutations {
        let n = bytes.len();
        match *m {
            Mutation::Flip { at, bit } if n > 0 => {
                let i = index(at, n - 1);
                bytes[i] ^= 1 << bit;
            }
            Mutation::Flip { .. } => {}
            Mutation::Insert { at, byte } => bytes.insert(index(at, n), byte),
            Mutation::Delete { at, len } => {
                let i = index(at, n);
                bytes.drain(i..(i + len).min(n));
            }
            Mutation::Token { at, token } => {
                let i = index(at, n);
                bytes.splice(i..i, TOKENS[token].bytes());
            }
            Mutation::Duplicate { from, len, to } => {
                let i = index(from, n);
                let piece: Vec<u8> = bytes[i..(i + len).min(n)].to_vec();
                let j = index(to, n);
                bytes.splice(j..j, piece);
            }
            Mutation::Truncate { at } => bytes.truncate(index(at, n)),
        }
    }
    bytes
}

/// Valid inputs mutated 1 to 8 times.
fn mutated(seed: &'static [u8]) -> impl Strategy<Value = Vec<u8>> {
    proptest::collection::vec(mutation(), 1..8).prop_map(move |m| mutate(seed, &m))
}

/// Random bytes, some of them starting like the format.
fn random_bytes(prefix: &'static [u8]) -> impl Strategy<Value = Vec<u8>> {
    (
        any::<bool>(),
        proptest::collection::vec(any::<u8>(), 0..512),
    )
        .prop_map(move |(keep, tail)| {
            let mut bytes = if keep { prefix.to_vec() } else { Vec::new() };
            bytes.extend(tail);
            bytes
        })
}

fn cases(default: u32) -> u32 {
    std::env::var("FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// Every CSV table shape the commands read.
fn parse_csv(bytes: &[u8]) {
    let path = Path::new("fuzz.csv");
    let _ = read_table_from(bytes, path, ["x", "y", "z"]);
    let _ = read_table_from(bytes, path, ["u", "v"]);
    let _ = read_table_from(bytes, path, ["ul", "vl", "ur", "vr"]);
    // Streaming in small chunks: the reader's line bookkeeping across chunk ends.
    if let Ok(mut reader) = TableReader::from_reader(bytes, path, ["x", "y", "z"]) {
        let mut rows = Vec::new();
        while let Ok(n) = reader.next_chunk(2, &mut rows) {
            if n == 0 {
                break;
            }
        }
    }
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// The file readers, on bytes that need not be UTF-8.
fn parse_files(bytes: &[u8]) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("input");
    std::fs::write(&path, bytes).unwrap();
    let _ = read_rig(&path);
    let _ = read_observations(&path);
    let _ = read_truth(&path);
    let _ = flatport::io::read_opencv_stereo(&path);
    let _ = flatport::io::npy::read_npy(&path);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: cases(1500), failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn rig_json_never_panics(bytes in prop_oneof![mutated(RIG.as_bytes()), random_bytes(b"{\"cameras\": [")]) {
        let _ = rig_from_json_str(&text(&bytes), Path::new("rig.json"));
    }

    #[test]
    fn observations_json_never_panics(bytes in prop_oneof![mutated(OBSERVATIONS.as_bytes()), random_bytes(b"{\"board\": ")]) {
        let _ = observations_from_json_str(&text(&bytes), Path::new("obs.json"));
    }

    #[test]
    fn opencv_yaml_never_panics(bytes in prop_oneof![mutated(YAML.as_bytes()), random_bytes(b"%YAML:1.0\n")]) {
        let _ = parse_opencv_stereo(&text(&bytes), Path::new("stereo.yml"));
    }

    #[test]
    fn csv_never_panics(bytes in prop_oneof![mutated(CSV.as_bytes()), random_bytes(b"x,y,z\n")]) {
        parse_csv(&bytes);
    }

    #[test]
    fn npy_never_panics(bytes in prop_oneof![mutated(NPY.as_slice()), random_bytes(b"\x93NUMPY\x01\x00")]) {
        let _ = npy_from_bytes(&bytes, Path::new("cost.npy"));
    }
}

proptest! {
    // Through files (UTF-8 checks, the truth reader): fewer cases, each writes a file.
    #![proptest_config(ProptestConfig { cases: cases(300), failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn file_readers_never_panic(bytes in prop_oneof![
        mutated(RIG.as_bytes()), mutated(OBSERVATIONS.as_bytes()), mutated(TRUTH.as_bytes()), mutated(YAML.as_bytes()),
        mutated(NPY.as_slice()), random_bytes(b"{"),
    ]) {
        parse_files(&bytes);
    }
}

/// A valid `.npy` file: shape (2, 3), six f64 values, as `NpyWriter` writes it.
static NPY: std::sync::LazyLock<Vec<u8>> = std::sync::LazyLock::new(|| {
    let mut bytes = flatport::io::npy::npy_header(&[2, 3]);
    for v in [1.0f64, -2.5, 0.0, f64::INFINITY, 1e-300, 6.0] {
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    bytes
});

/// The seeds themselves parse: the mutations start from valid inputs.
#[test]
fn seeds_are_valid() {
    rig_from_json_str(RIG, Path::new("rig.json")).unwrap();
    observations_from_json_str(OBSERVATIONS, Path::new("obs.json")).unwrap();
    parse_opencv_stereo(YAML, Path::new("stereo.yml")).unwrap();
    assert_eq!(
        read_table_from(CSV.as_bytes(), Path::new("p.csv"), ["x", "y", "z"])
            .unwrap()
            .len(),
        4
    );
    assert_eq!(
        npy_from_bytes(&NPY, Path::new("a.npy")).unwrap().0,
        vec![2, 3]
    );
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("truth.json");
    std::fs::write(&path, TRUTH).unwrap();
    read_truth(&path).unwrap();
}
