//! Row-by-row evaluation with the CSV contract: results keep input order, rows without an answer
//! become NaN rows, and the reasons are counted for stderr.

use std::collections::BTreeMap;
use std::path::Path;

use flatport::io::write_table;
use flatport::model::NoSolution;

/// Results of one batch, in input order.
pub struct Batch<const M: usize> {
    pub rows: Vec<Result<[f64; M], NoSolution>>,
}

impl<const M: usize> Batch<M> {
    /// Evaluates `f` on every input row.
    pub fn map<const N: usize>(inputs: &[[f64; N]], f: impl Fn(&[f64; N]) -> Result<[f64; M], NoSolution>) -> Self {
        Self { rows: inputs.iter().map(f).collect() }
    }

    /// Rows without an answer, by reason.
    pub fn rejections(&self) -> BTreeMap<u32, (NoSolution, usize)> {
        let mut counts = BTreeMap::new();
        for reason in self.rows.iter().filter_map(|r| r.err()) {
            counts.entry(reason.code()).or_insert((reason, 0)).1 += 1;
        }
        counts
    }

    /// Writes the table (stdout when `output` is `None`) and reports NaN rows on stderr.
    pub fn write(&self, output: Option<&Path>, header: [&str; M]) -> anyhow::Result<()> {
        let summary = write_table(output, header, self.rows.iter().map(|r| r.ok()))?;
        report_rejections(summary.rows, &self.rejections());
        Ok(())
    }
}

/// `3 of 100 rows have no answer (written as NaN): 2 point not in the water, 1 …`
pub fn report_rejections(total: usize, rejections: &BTreeMap<u32, (NoSolution, usize)>) {
    let nan_rows: usize = rejections.values().map(|(_, n)| n).sum();
    if nan_rows == 0 {
        return;
    }
    let reasons: Vec<String> = rejections.values().map(|(reason, n)| format!("{n} {reason}")).collect();
    eprintln!(
        "{nan_rows} of {total} rows have no answer (written as NaN): {}",
        reasons.join(", ")
    );
}
