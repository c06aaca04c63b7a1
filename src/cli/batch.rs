//! Streams a CSV through the engine with the CSV contract: results keep input order, rows without
//! an answer become NaN rows and their reasons are counted on stderr, and malformed input leaves
//! nothing written. Memory stays bounded: the input is read and written in chunks of
//! [`CHUNK_ROWS`] rows, whatever its size.

use std::collections::BTreeMap;
use std::io::{BufReader, IsTerminal, Seek};
use std::path::Path;

use flatport::engine::{Engine, EngineError};
use flatport::io::{IoError, TableReader, TableSource, TableWriter, validate_table};
use flatport::model::NoSolution;

/// Rows per chunk: 1 Mi rows is 48 MiB of 6-column output in f64.
pub const CHUNK_ROWS: usize = 1 << 20;

/// Reads `input` (columns `in_header`) in chunks, runs `run` on each, writes the `out_header`
/// columns to `output` (standard output when `None`). Every input is read once as a stream of
/// bytes, and malformed input writes nothing:
/// - into a regular file (or a new path), the output goes to a temporary file that replaces the
///   target only at the end;
/// - onto an output that cannot be taken back (standard output, a device, a FIFO), the whole input
///   is checked first ([`checked_input`]) before the first row goes out.
pub fn stream<const N: usize, const M: usize>(
    engine: &Engine,
    input: &Path,
    in_header: [&str; N],
    output: Option<&Path>,
    out_header: [&str; M],
    run: impl Fn(&Engine, &[[f64; N]], &mut [[f64; M]], &mut [u32]) -> Result<(), EngineError>,
) -> anyhow::Result<()> {
    let mut writer = TableWriter::create(output, out_header)?;
    let (mut reader, total) = if writer.streams() {
        let (reader, total) = checked_input(input, in_header)?;
        (reader, Some(total))
    } else {
        (TableReader::open(input, in_header)?, None)
    };
    let (mut rows, mut results, mut status) = (Vec::new(), Vec::new(), Vec::new());
    let mut rejections: BTreeMap<u32, (NoSolution, usize)> = BTreeMap::new();
    let progress = std::io::stderr().is_terminal();
    let mut done = 0u64;
    while reader.next_chunk(CHUNK_ROWS, &mut rows)? > 0 {
        results.resize(rows.len(), [0.0; M]);
        status.resize(rows.len(), 0);
        run(engine, &rows, &mut results, &mut status)?;
        for &code in status.iter().filter(|&&s| s != 0) {
            let reason = NoSolution::from_code(code).expect("engines return NoSolution codes");
            rejections.entry(code).or_insert((reason, 0)).1 += 1;
        }
        writer.write_rows(
            results
                .iter()
                .zip(&status)
                .map(|(r, &s)| (s == 0).then_some(*r)),
        )?;
        done += rows.len() as u64;
        if progress {
            match total {
                Some(t) => eprint!(
                    "\r{done} of {t} rows ({:.0} %)",
                    100.0 * done as f64 / t.max(1) as f64
                ),
                None => eprint!("\r{done} rows"),
            }
        }
    }
    if progress && done > 0 {
        eprintln!();
    }
    let summary = writer.finish()?;
    report_rejections(summary.rows, &rejections);
    Ok(())
}

/// Checks the whole of `input` (every line parsed, errors naming its line and column) and returns
/// a reader over it from the start, with its row count.
///
/// A regular file is read twice, checked and then streamed. Anything else (standard input `-`,
/// a pipe such as `<(…)` or `/dev/stdin`, a FIFO) can be read only once: its bytes are copied
/// into an unnamed temporary file (in `$TMPDIR`, removed by the system when closed, even if the
/// process is killed), which is checked and then streamed.
pub fn checked_input<const N: usize>(
    input: &Path,
    header: [&str; N],
) -> Result<(TableReader<N>, u64), IoError> {
    let from_stdin = input.as_os_str() == "-";
    if !from_stdin && std::fs::metadata(input).is_ok_and(|m| m.is_file()) {
        let total = validate_table(input, header)?;
        return Ok((TableReader::open(input, header)?, total));
    }
    let read_error = |source| IoError::Read {
        path: input.to_path_buf(),
        source,
    };
    let mut spool = tempfile::tempfile().map_err(|e| {
        read_error(std::io::Error::new(
            e.kind(),
            format!(
                "cannot make a temporary copy of the input in {}: {e}",
                std::env::temp_dir().display()
            ),
        ))
    })?;
    let copied = if from_stdin {
        std::io::copy(&mut std::io::stdin().lock(), &mut spool)
    } else {
        std::fs::File::open(input).and_then(|mut source| std::io::copy(&mut source, &mut spool))
    };
    copied.map_err(read_error)?;
    spool.rewind().map_err(read_error)?;
    // The clone shares the file offset: rewound again once the check has read to the end.
    let check_handle = spool.try_clone().map_err(read_error)?;
    let mut check = TableReader::from_reader(
        Box::new(BufReader::new(check_handle)) as TableSource,
        input,
        header,
    )?;
    while check.next_row()?.is_some() {}
    let total = check.rows_read();
    drop(check);
    spool.rewind().map_err(read_error)?;
    let reader = TableReader::from_reader(
        Box::new(BufReader::new(spool)) as TableSource,
        input,
        header,
    )?;
    Ok((reader, total))
}

/// `3 of 100 rows have no answer (written as NaN): 2 point not in the water, 1 …`
pub fn report_rejections(total: usize, rejections: &BTreeMap<u32, (NoSolution, usize)>) {
    let nan_rows: usize = rejections.values().map(|(_, n)| n).sum();
    if nan_rows == 0 {
        return;
    }
    let reasons: Vec<String> = rejections
        .values()
        .map(|(reason, n)| format!("{n} {reason}"))
        .collect();
    eprintln!(
        "{nan_rows} of {total} rows have no answer (written as NaN): {}",
        reasons.join(", ")
    );
}
