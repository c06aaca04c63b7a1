//! Streams a CSV through the engine with the CSV contract: results keep input order, rows without
//! an answer become NaN rows and their reasons are counted on stderr, and malformed input leaves
//! nothing written. Memory stays bounded: the input is read and written in chunks of
//! [`CHUNK_ROWS`] rows, whatever its size.

use std::collections::BTreeMap;
use std::io::IsTerminal;
use std::path::Path;

use flatport::engine::{Engine, EngineError};
use flatport::io::{TableReader, TableWriter, validate_table};
use flatport::model::NoSolution;

/// Rows per chunk: 1 Mi rows is 48 MiB of 6-column output in f64.
pub const CHUNK_ROWS: usize = 1 << 20;

/// Reads `input` (columns `in_header`) in chunks, runs `run` on each, writes the `out_header`
/// columns to `output` (standard output when `None`). With standard output the input file is
/// first checked whole, so that a bad line writes nothing; a file is written through a temporary
/// file that replaces it only at the end. (From standard input to standard output a bad line
/// stops the output where it is.)
pub fn stream<const N: usize, const M: usize>(
    engine: &Engine,
    input: &Path,
    in_header: [&str; N],
    output: Option<&Path>,
    out_header: [&str; M],
    run: impl Fn(&Engine, &[[f64; N]], &mut [[f64; M]], &mut [u32]) -> Result<(), EngineError>,
) -> anyhow::Result<()> {
    // Standard input can be read only once: it is not checked ahead.
    let from_stdin = input == Path::new("-");
    let total = if output.is_none() && !from_stdin { Some(validate_table(input, in_header)?) } else { None };
    let mut reader = TableReader::open(input, in_header)?;
    let mut writer = TableWriter::create(output, out_header)?;
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
        writer.write_rows(results.iter().zip(&status).map(|(r, &s)| (s == 0).then_some(*r)))?;
        done += rows.len() as u64;
        if progress {
            match total {
                Some(t) => eprint!("\r{done} of {t} rows ({:.0} %)", 100.0 * done as f64 / t.max(1) as f64),
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

/// `3 of 100 rows have no answer (written as NaN): 2 point not in the water, 1 …`
pub fn report_rejections(total: usize, rejections: &BTreeMap<u32, (NoSolution, usize)>) {
    let nan_rows: usize = rejections.values().map(|(_, n)| n).sum();
    if nan_rows == 0 {
        return;
    }
    let reasons: Vec<String> = rejections.values().map(|(reason, n)| format!("{n} {reason}")).collect();
    eprintln!("{nan_rows} of {total} rows have no answer (written as NaN): {}", reasons.join(", "));
}
