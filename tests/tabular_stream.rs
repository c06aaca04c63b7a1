//! Streaming CSV tables: `TableReader` reads what `read_table` reads, chunk by chunk, with the same
//! errors; `TableWriter` writes the bytes `write_table` writes and puts a file in place only on
//! `finish`; a long round trip keeps every value bit for bit.
//!
//! Throughput for 6 million rows of 2 and 6 columns (rows/s, printed, not asserted):
//! `cargo test --release --test tabular_stream -- --ignored --nocapture`.

use std::path::{Path, PathBuf};
use std::time::Instant;

use flatport::io::{
    IoError, TableReader, TableWriteSummary, TableWriter, read_table, read_table_from,
    validate_table, write_table,
};

/// splitmix64: a small deterministic generator, so rows can be made again to check them.
struct Random(u64);

impl Random {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Mostly full-precision values in [-1000, 1000) (what the commands write: ~17 significant
    /// digits); every 997th value an edge case: extremes, subnormals, −0, or any finite bit
    /// pattern (up to ~330 characters in positional notation).
    fn value(&mut self) -> f64 {
        let bits = self.next();
        if !bits.is_multiple_of(997) {
            return (bits >> 11) as f64 / (1u64 << 53) as f64 * 2000.0 - 1000.0;
        }
        const EDGES: [f64; 9] = [
            -0.0,
            0.0,
            5e-324,
            f64::MAX,
            f64::MIN,
            f64::MIN_POSITIVE,
            0.30000000000000004,
            1e-7,
            123_456_789_012_345_680.0,
        ];
        let pick = self.next();
        match EDGES.get((pick % 16) as usize) {
            Some(&edge) => edge,
            None => loop {
                let any = f64::from_bits(self.next());
                if any.is_finite() {
                    break any;
                }
            },
        }
    }

    fn row<const M: usize>(&mut self) -> [f64; M] {
        std::array::from_fn(|_| self.value())
    }
}

fn bits<const N: usize>(rows: &[[f64; N]]) -> Vec<[u64; N]> {
    rows.iter().map(|r| r.map(f64::to_bits)).collect()
}

fn names(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

/// Every row of `path` through `TableReader` in chunks of `size`, checking the chunk lengths.
fn read_in_chunks<const N: usize>(path: &Path, header: [&str; N], size: usize) -> Vec<[f64; N]> {
    let mut reader = TableReader::open(path, header).unwrap();
    let (mut all, mut chunk) = (Vec::new(), vec![[7.0; N]; 3]);
    let mut short = false;
    loop {
        let count = reader.next_chunk(size, &mut chunk).unwrap();
        assert_eq!(count, chunk.len(), "the count is the rows in the chunk");
        if count == 0 {
            break;
        }
        assert!(!short, "only the last chunk is short");
        assert!(count <= size.max(1));
        short = count < size.max(1);
        all.extend_from_slice(&chunk);
        assert_eq!(reader.rows_read(), all.len() as u64);
    }
    // The end stays the end.
    assert_eq!(reader.next_chunk(size, &mut chunk).unwrap(), 0);
    assert!(chunk.is_empty());
    all
}

/// A table of 100 rows with the things the reader must take: spaces, blank lines, CRLF, quotes,
/// a byte-order mark, numbers without digits on one side of the point.
fn messy_table(random: &mut Random) -> String {
    let mut text = String::from("\u{feff} x , y ,z\r\n\n");
    for i in 0..100 {
        let [x, y, z]: [f64; 3] = random.row();
        match i % 5 {
            0 => text.push_str(&format!("{x},{y},{z}\n")),
            1 => text.push_str(&format!(" {x} , \"{y}\" ,{z}\r\n")),
            2 => text.push_str(&format!("{x:e},{y:e},{z:e}\n\n  \n")),
            3 => text.push_str(&format!("{x},.5,2.\n")),
            _ => text.push_str(&format!("{x:.3},{y},{}\n", -z)),
        }
    }
    text
}

#[test]
fn chunks_give_the_rows_of_read_table() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("points.csv");
    std::fs::write(&path, messy_table(&mut Random(1))).unwrap();
    let header = ["x", "y", "z"];
    let whole = read_table(&path, header).unwrap();
    assert_eq!(whole.len(), 100);
    // 0 is taken as 1, so a chunk of 0 rows always means the end.
    for size in [1, 7, 100, 101, 1000, usize::MAX, 0] {
        let chunked = read_in_chunks(&path, header, size);
        assert_eq!(bits(&chunked), bits(&whole), "chunks of {size}");
    }
    assert_eq!(validate_table(&path, header).unwrap(), 100);

    // From a reader, and one row at a time.
    let text = std::fs::read(&path).unwrap();
    let mut reader = TableReader::from_reader(&text[..], &path, header).unwrap();
    let mut one_by_one = Vec::new();
    while let Some(row) = reader.next_row().unwrap() {
        one_by_one.push(row);
    }
    assert_eq!(bits(&one_by_one), bits(&whole));
    assert_eq!(reader.line(), text.split(|&b| b == b'\n').count() - 1);

    // Header-only and blank-only tables.
    for text in ["x,y,z", "x,y,z\n", "\n x , y , z \n\n\n"] {
        let mut reader = TableReader::from_reader(text.as_bytes(), &path, header).unwrap();
        let mut chunk = Vec::new();
        assert_eq!(reader.next_chunk(7, &mut chunk).unwrap(), 0);
    }
}

#[test]
fn header_errors_match_read_table() {
    let dir = tempfile::tempdir().unwrap();
    for (text, expected) in [
        (
            "x,y,w\n1,2,3\n",
            "x.csv:1: column '3': header is 'x,y,w', expected 'x,y,z'",
        ),
        (
            "",
            "x.csv:1: column '1': file is empty; expected the header 'x,y,z'",
        ),
        (
            "\n\nX,y,z\n",
            "x.csv:3: column '1': header is 'X,y,z', expected 'x,y,z'",
        ),
        (
            "x,y\n1,2\n",
            "x.csv:1: column '3': header is 'x,y', expected 'x,y,z'",
        ),
    ] {
        let path = dir.path().join("x.csv");
        std::fs::write(&path, text).unwrap();
        let expected = expected.replace("x.csv", &path.display().to_string());
        let streamed = TableReader::open(&path, ["x", "y", "z"]).unwrap_err();
        assert_eq!(streamed.to_string(), expected);
        assert_eq!(
            read_table(&path, ["x", "y", "z"]).unwrap_err().to_string(),
            expected
        );
        assert_eq!(
            validate_table(&path, ["x", "y", "z"])
                .unwrap_err()
                .to_string(),
            expected
        );
    }
    let missing = dir.path().join("missing.csv");
    let error = TableReader::open(&missing, ["u", "v"]).unwrap_err();
    assert!(matches!(error, IoError::Read { .. }), "{error:?}");
    assert!(matches!(
        validate_table(&missing, ["u", "v"]),
        Err(IoError::Read { .. })
    ));
}

#[test]
fn errors_in_a_later_chunk_name_line_and_column() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("matches.csv");
    let header = ["ul", "vl", "ur", "vr"];
    // Line 1 the header, line 2 blank, then 60 good rows with a blank line after every tenth:
    // the bad line is line 69, after 60 good rows (8 full chunks of 7 and 4 rows).
    let mut good = String::from("ul,vl,ur,vr\n\n");
    let mut random = Random(2);
    for i in 0..60 {
        let [a, b, c, d]: [f64; 4] = random.row();
        good.push_str(&format!("{a},{b},{c},{d}\n"));
        if i % 10 == 9 {
            good.push('\n');
        }
    }
    let good_lines = good.lines().count();
    assert_eq!(good_lines, 68);
    let cases: [(&[u8], usize, &str, &str); 7] = [
        (b"1,2,abc,4", 69, "ur", "not a number: \"abc\""),
        (b"1,2,,4", 69, "ur", "not a number: \"\""),
        (
            b"1,2,3",
            69,
            "vr",
            "line has 3 values, expected 4 (ul,vl,ur,vr)",
        ),
        (
            b"1,2,3,4,5",
            69,
            "5",
            "line has 5 values, expected 4 (ul,vl,ur,vr)",
        ),
        (
            b"1,2,3,NaN",
            69,
            "vr",
            "must be a finite number, got \"NaN\"",
        ),
        (
            b"1,-inf,3,4",
            69,
            "vl",
            "must be a finite number, got \"-inf\"",
        ),
        (b"1,2,\xff,4", 69, "ur", "not valid UTF-8 text"),
    ];
    for (bad, line, column, reason) in cases {
        let mut text = good.clone().into_bytes();
        text.extend_from_slice(bad);
        text.extend_from_slice(b"\n1,2,3,4\n");
        std::fs::write(&path, &text).unwrap();
        let expected = format!("{}:{line}: column '{column}': {reason}", path.display());

        let mut reader = TableReader::open(&path, header).unwrap();
        let mut chunk = Vec::new();
        for _ in 0..8 {
            assert_eq!(reader.next_chunk(7, &mut chunk).unwrap(), 7);
        }
        let error = reader.next_chunk(7, &mut chunk).unwrap_err();
        assert_eq!(chunk.len(), 4, "the good rows before the bad line");
        assert_eq!(reader.rows_read(), 60);
        match &error {
            IoError::Csv {
                line: l, column: c, ..
            } => assert_eq!((*l, c.as_str()), (line, column)),
            other => panic!("expected IoError::Csv, got {other:?}"),
        }
        assert_eq!(error.to_string(), expected);
        // The same error, word for word, from every entry point.
        assert_eq!(read_table(&path, header).unwrap_err().to_string(), expected);
        let from = read_table_from(&text[..], &path, header).unwrap_err();
        assert_eq!(from.to_string(), expected);
        assert_eq!(
            validate_table(&path, header).unwrap_err().to_string(),
            expected
        );
        // One chunk larger than the file fails the same way.
        let mut reader = TableReader::open(&path, header).unwrap();
        let error = reader.next_chunk(usize::MAX, &mut chunk).unwrap_err();
        assert_eq!(error.to_string(), expected);
    }
}

/// Rows with every kind of value the writer meets, and rows without an answer.
fn rows_with_gaps<const M: usize>(count: usize, seed: u64) -> Vec<Option<[f64; M]>> {
    let mut random = Random(seed);
    (0..count)
        .map(|i| (i % 13 != 4).then(|| random.row()))
        .collect()
}

#[test]
fn writer_bytes_equal_write_table() {
    let dir = tempfile::tempdir().unwrap();
    fn check<const M: usize>(dir: &Path, header: [&str; M]) {
        let rows = rows_with_gaps::<M>(5000, M as u64);
        let whole = dir.join(format!("whole{M}.csv"));
        let streamed = dir.join(format!("streamed{M}.csv"));
        let expected = write_table(Some(&whole), header, rows.iter().copied()).unwrap();
        let mut writer = TableWriter::create(Some(&streamed), header).unwrap();
        for chunk in rows.chunks(7) {
            writer.write_rows(chunk.iter().copied()).unwrap();
        }
        assert_eq!(writer.summary(), expected);
        let summary = writer.finish().unwrap();
        assert_eq!(summary, expected);
        assert_eq!(summary.rows, 5000);
        assert_eq!(
            summary.nan_rows,
            rows.iter().filter(|r| r.is_none()).count()
        );
        let (a, b) = (
            std::fs::read(&whole).unwrap(),
            std::fs::read(&streamed).unwrap(),
        );
        assert!(a == b, "{M} columns: TableWriter and write_table differ");
        // Spot-check the format itself (fixed by write_table's unit tests).
        let text = String::from_utf8(b).unwrap();
        assert_eq!(text.lines().next(), Some(header.join(",").as_str()));
        assert_eq!(text.lines().nth(5), Some(vec!["NaN"; M].join(",").as_str()));
    }
    check(dir.path(), ["u", "v"]);
    check(dir.path(), ["ox", "oy", "oz", "dx", "dy", "dz"]);
    // No rows: the header alone.
    let empty = dir.path().join("empty.csv");
    let summary = TableWriter::create(Some(&empty), ["u", "v"])
        .unwrap()
        .finish()
        .unwrap();
    assert_eq!(
        summary,
        TableWriteSummary {
            rows: 0,
            nan_rows: 0
        }
    );
    assert_eq!(std::fs::read_to_string(&empty).unwrap(), "u,v\n");
}

#[test]
fn dropped_writer_leaves_no_file_and_no_temporary() {
    let dir = tempfile::tempdir().unwrap();
    let target = dir.path().join("out.csv");
    let mut writer = TableWriter::create(Some(&target), ["u", "v"]).unwrap();
    // More than the buffer holds, so the temporary file has content on disk.
    writer.write_rows(rows_with_gaps::<2>(50_000, 3)).unwrap();
    let during = names(dir.path());
    assert_eq!(during.len(), 1, "{during:?}");
    assert!(
        during[0].starts_with(".out.csv.") && during[0].ends_with(".tmp"),
        "{during:?}"
    );
    assert!(
        std::fs::metadata(dir.path().join(&during[0]))
            .unwrap()
            .len()
            > 100_000
    );
    drop(writer);
    assert!(names(dir.path()).is_empty(), "{:?}", names(dir.path()));

    // An existing target keeps its old content.
    std::fs::write(&target, "old").unwrap();
    let mut writer = TableWriter::create(Some(&target), ["u", "v"]).unwrap();
    writer.write_rows([Some([1.0, 2.0])]).unwrap();
    drop(writer);
    assert_eq!(names(dir.path()), ["out.csv"]);
    assert_eq!(std::fs::read_to_string(&target).unwrap(), "old");

    // Unwinding out of a run drops the writer too.
    let result = std::panic::catch_unwind(|| {
        let mut writer = TableWriter::create(Some(&target), ["u", "v"]).unwrap();
        writer.write_rows([Some([1.0, 2.0])]).unwrap();
        panic!("interrupted");
    });
    assert!(result.is_err());
    assert_eq!(names(dir.path()), ["out.csv"]);
    assert_eq!(std::fs::read_to_string(&target).unwrap(), "old");
}

#[test]
fn finish_renames_the_whole_file_into_place() {
    let dir = tempfile::tempdir().unwrap();
    let target = dir.path().join("out.csv");
    std::fs::write(&target, "old").unwrap();
    let mut writer = TableWriter::create(Some(&target), ["u", "v"]).unwrap();
    let rows = rows_with_gaps::<2>(50_000, 4);
    writer.write_rows(rows.iter().copied()).unwrap();
    // Until finish the target is untouched.
    assert_eq!(std::fs::read_to_string(&target).unwrap(), "old");
    assert_eq!(names(dir.path()).len(), 2);
    let summary = writer.finish().unwrap();
    assert_eq!(summary.rows, 50_000);
    assert_eq!(names(dir.path()), ["out.csv"]);
    let reference = dir.path().join("reference.csv");
    write_table(Some(&reference), ["u", "v"], rows).unwrap();
    assert!(std::fs::read(&target).unwrap() == std::fs::read(&reference).unwrap());

    // A folder as the target is refused at once, naming it, and left as it was.
    let folder = dir.path().join("taken");
    std::fs::create_dir(&folder).unwrap();
    std::fs::write(folder.join("inside.txt"), "keep").unwrap();
    let error = TableWriter::<2>::create(Some(&folder), ["u", "v"]).unwrap_err();
    assert!(
        error.to_string().starts_with(&folder.display().to_string()),
        "{error}"
    );
    assert!(error.to_string().contains("folder"), "{error}");
    // A rename that fails (the target became a non-empty folder while the table was written)
    // removes the temporary file and leaves the folder as it was.
    std::fs::remove_dir_all(&folder).unwrap();
    let mut writer = TableWriter::create(Some(&folder), ["u", "v"]).unwrap();
    writer.write_rows([Some([1.0, 2.0])]).unwrap();
    std::fs::create_dir(&folder).unwrap();
    std::fs::write(folder.join("inside.txt"), "keep").unwrap();
    let error = writer.finish().unwrap_err();
    assert!(matches!(error, IoError::Write { .. }), "{error:?}");
    assert!(
        error.to_string().starts_with(&folder.display().to_string()),
        "{error}"
    );
    assert_eq!(names(dir.path()), ["out.csv", "reference.csv", "taken"]);
    assert_eq!(
        std::fs::read_to_string(folder.join("inside.txt")).unwrap(),
        "keep"
    );

    // A missing folder fails at create, naming the target.
    let missing = dir.path().join("no_such_dir").join("out.csv");
    let error = TableWriter::create(Some(&missing), ["u", "v"]).unwrap_err();
    assert!(matches!(error, IoError::Write { .. }), "{error:?}");
    assert!(error.to_string().contains("out.csv"), "{error}");
}

#[test]
fn readers_and_writers_can_move_to_threads() {
    fn send<T: Send>() {}
    send::<TableReader<3>>();
    send::<TableWriter<6>>();
}

/// Rows per second of one streaming round trip through a file.
struct Throughput {
    write: f64,
    validate: f64,
    read: f64,
    bytes: u64,
}

/// Writes `count` rows of M columns through `TableWriter` in chunks, validates the file, reads it
/// back through `TableReader` in chunks and checks every value bit for bit against the same rows
/// made again. Never holds more than one chunk.
fn round_trip<const M: usize>(dir: &Path, count: usize) -> Throughput {
    const CHUNK: usize = 1 << 16;
    let header: [String; M] = std::array::from_fn(|i| format!("c{i}"));
    let header: [&str; M] = std::array::from_fn(|i| header[i].as_str());
    let path: PathBuf = dir.join(format!("round_trip_{M}.csv"));

    let start = Instant::now();
    let mut random = Random(M as u64 * 1000);
    let mut writer = TableWriter::create(Some(&path), header).unwrap();
    let mut left = count;
    while left > 0 {
        let n = left.min(CHUNK);
        writer
            .write_rows((0..n).map(|_| Some(random.row::<M>())))
            .unwrap();
        left -= n;
    }
    assert_eq!(
        writer.finish().unwrap(),
        TableWriteSummary {
            rows: count,
            nan_rows: 0
        }
    );
    let write = count as f64 / start.elapsed().as_secs_f64();
    let bytes = std::fs::metadata(&path).unwrap().len();

    let start = Instant::now();
    assert_eq!(validate_table(&path, header).unwrap(), count as u64);
    let validate = count as f64 / start.elapsed().as_secs_f64();

    let start = Instant::now();
    let mut random = Random(M as u64 * 1000);
    let mut reader = TableReader::open(&path, header).unwrap();
    let mut chunk = Vec::new();
    let mut seen = 0;
    while reader.next_chunk(CHUNK, &mut chunk).unwrap() > 0 {
        for (i, row) in chunk.iter().enumerate() {
            let expected = random.row::<M>();
            if row.map(f64::to_bits) != expected.map(f64::to_bits) {
                panic!("row {}: read {row:?}, wrote {expected:?}", seen + i);
            }
        }
        seen += chunk.len();
    }
    assert_eq!(seen, count);
    let read = count as f64 / start.elapsed().as_secs_f64();
    std::fs::remove_file(&path).unwrap();
    Throughput {
        write,
        validate,
        read,
        bytes,
    }
}

fn report<const M: usize>(dir: &Path, count: usize) {
    let t = round_trip::<M>(dir, count);
    println!(
        "{count} rows x {M} columns ({:.0} MB): write {:.2e} rows/s, validate {:.2e} rows/s, \
         read {:.2e} rows/s (incl. making the rows again to compare)",
        t.bytes as f64 / 1e6,
        t.write,
        t.validate,
        t.read
    );
}

#[test]
fn six_million_rows_round_trip_bit_exact() {
    let dir = tempfile::tempdir().unwrap();
    report::<2>(dir.path(), 6_000_000);
}

#[test]
#[ignore = "throughput measurement: writes ~1 GB; run with --ignored --nocapture"]
fn throughput_two_and_six_columns() {
    let dir = tempfile::tempdir().unwrap();
    report::<2>(dir.path(), 6_000_000);
    report::<6>(dir.path(), 6_000_000);
}
