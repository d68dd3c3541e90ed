//! An experiment's results as files and tables: `results.csv` (one row per cell) and back, the
//! matrix's table (method × prior, by view count) and the configurations table (per method and
//! view count: runs, wall-clock, scores), which the README's table is generated from.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::error::{CoreError, Result};

/// The numbers of one finished cell (non-finite values stored as `null`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CellResult {
    pub case: String,
    pub method: String,
    pub views: usize,
    pub view_list: String,
    pub prior: String,
    pub prior_threshold_mm: Option<f64>,
    pub seconds: f64,
    pub gaussians: usize,
    pub metrics: BTreeMap<String, Option<f64>>,
    /// The cell's configuration when it ran ([`crate::run::experiment::Cell::config_hash`]); a result of another
    /// configuration (or of a version that did not record it) is not this cell's.
    #[serde(default)]
    pub config_hash: Option<String>,
    /// The case it ran on (`CaseFile::fingerprint` of its `case.json`, before another prior
    /// was swapped in); a result on a case since re-made is not this cell's. `None` in cells of
    /// versions that did not record it (taken as the case's).
    #[serde(default)]
    pub case_fingerprint: Option<String>,
    /// The digest of the files it read from the case
    /// ([`case_files_digest`](crate::run::experiment::case_files_digest)); a result on a view,
    /// prior or ground truth since re-made is not this cell's. `None` in cells of versions that
    /// did not record it (taken as the case's).
    #[serde(default)]
    pub case_files: Option<String>,
}

/// The cell columns of `results.csv` before the metrics.
const CELL_COLUMNS: [&str; 8] =
    ["case", "method", "views", "view_list", "prior", "prior_threshold_mm", "seconds", "gaussians"];

pub(super) fn mean_std(v: &[f64]) -> Option<(f64, f64)> {
    if v.is_empty() {
        return None;
    }
    let m = v.iter().sum::<f64>() / v.len() as f64;
    let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64;
    Some((m, var.sqrt()))
}

/// Mean ± std of a metric over the results; cells where it is undefined (e.g. no point in the
/// ROI) are counted and shown.
fn cell_text(rs: &[&CellResult], key: &str) -> String {
    let vals: Vec<f64> = rs.iter().filter_map(|r| r.metrics.get(key).copied().flatten()).collect();
    let missing = rs.len() - vals.len();
    let core = match mean_std(&vals) {
        Some((m, s)) => format!("{m:.2} ± {s:.2}"),
        None => "—".into(),
    };
    if missing > 0 { format!("{core} ({missing}× ∞)") } else { core }
}

pub(super) fn priors_of(results: &[CellResult]) -> Vec<String> {
    results.iter().map(|r| r.prior.clone()).collect::<BTreeSet<_>>().into_iter().collect()
}

/// `field` as one CSV field (RFC 4180): quoted, with quotes doubled, when it holds a comma, a
/// quote or a line break.
fn csv_field(field: &str) -> String {
    if field.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", field.replace('"', "\"\""))
    } else {
        field.to_string()
    }
}

/// One CSV row per cell (undefined metrics as `inf`), the metrics' columns after the cell's.
pub fn results_csv(results: &[CellResult]) -> String {
    let keys: Vec<String> = results.first().map(|r| r.metrics.keys().cloned().collect()).unwrap_or_default();
    let mut csv =
        format!("case,method,views,view_list,prior,prior_threshold_mm,seconds,gaussians,{}\n", keys.join(","));
    for r in results {
        let vals: Vec<String> = keys
            .iter()
            .map(|k| r.metrics.get(k).copied().flatten().map_or("inf".into(), |v| format!("{v:.4}")))
            .collect();
        csv += &format!(
            "{},{},{},{},{},{},{:.1},{},{}\n",
            csv_field(&r.case),
            csv_field(&r.method),
            r.views,
            csv_field(&r.view_list),
            csv_field(&r.prior),
            r.prior_threshold_mm.map_or(String::new(), |v| format!("{v}")),
            r.seconds,
            r.gaussians,
            vals.join(",")
        );
    }
    csv
}

/// Markdown: rows = method (× prior), in the order of `methods`; columns = `view_counts` ×
/// (CD_ROI, HD95_ROI, CD, HD95).
pub fn results_table(results: &[CellResult], methods: &[String], view_counts: &[usize]) -> String {
    let cases: BTreeSet<&str> = results.iter().map(|r| r.case.as_str()).collect();
    let mut md = format!(
        "Mean ± std over {} case(s). CD = sum of the two one-sided mean distances (the reference's \
         convention), HD95 = 95th-percentile Hausdorff, in mm; ROI = the vessels missing from the prior.\n\n",
        cases.len()
    );
    let counts = view_counts.to_vec();
    md += "| method | prior |";
    for v in &counts {
        md += &format!(" CD_ROI ({v} views) | HD95_ROI ({v} views) | CD ({v} views) | HD95 ({v} views) |");
    }
    md += "\n|---|---|";
    for _ in &counts {
        md += "---:|---:|---:|---:|";
    }
    md += "\n";
    for m in methods {
        for p in &priors_of(results) {
            let sel: Vec<&CellResult> = results.iter().filter(|r| &r.method == m && &r.prior == p).collect();
            if sel.is_empty() {
                continue;
            }
            md += &format!("| {m} | {p} |");
            for v in &counts {
                let s: Vec<&CellResult> = sel.iter().copied().filter(|r| r.views == *v).collect();
                for key in ["roi_cd_sum_mm", "roi_hd95_mm", "cd_sum_mm", "hd95_mm"] {
                    md += &format!(" {} |", cell_text(&s, key));
                }
            }
            md += "\n";
        }
    }
    md
}

/// Reads a `results.csv` written by [`results_csv`] (`inf` = undefined); `path` names the file
/// in errors.
pub fn parse_results_csv(text: &str, path: &Path) -> Result<Vec<CellResult>> {
    let bad = |line: u64, problem: String| CoreError::format(path, format!("line {line}: {problem}"));
    let mut reader = csv::ReaderBuilder::new().has_headers(true).from_reader(text.as_bytes());
    let header: Vec<String> = reader.headers().map_err(|e| bad(1, e.to_string()))?.iter().map(str::to_string).collect();
    if header.len() < CELL_COLUMNS.len() || header[..CELL_COLUMNS.len()] != CELL_COLUMNS {
        return Err(bad(1, format!("the header must begin with {}", CELL_COLUMNS.join(","))));
    }
    let mut results = Vec::new();
    for record in reader.records() {
        let record = record.map_err(|e| bad(e.position().map_or(0, |p| p.line()), e.to_string()))?;
        let line = record.position().map_or(0, |p| p.line());
        let number = |i: usize| -> Result<f64> {
            let field = &record[i];
            field.parse::<f64>().map_err(|_| bad(line, format!("`{}` = `{field}` is not a number", header[i])))
        };
        let count = |i: usize| -> Result<usize> {
            let field = &record[i];
            field.parse::<usize>().map_err(|_| bad(line, format!("`{}` = `{field}` is not a count", header[i])))
        };
        let metrics = (CELL_COLUMNS.len()..header.len())
            .map(|i| Ok((header[i].clone(), Some(number(i)?).filter(|v| v.is_finite()))))
            .collect::<Result<BTreeMap<_, _>>>()?;
        results.push(CellResult {
            case: record[0].to_string(),
            method: record[1].to_string(),
            views: count(2)?,
            view_list: record[3].to_string(),
            prior: record[4].to_string(),
            prior_threshold_mm: if record[5].is_empty() { None } else { Some(number(5)?) },
            seconds: number(6)?,
            gaussians: count(7)?,
            metrics,
            config_hash: None,
            case_fingerprint: None,
            case_files: None,
        });
    }
    Ok(results)
}

/// The median of `v` (`None` when empty).
fn median(v: &[f64]) -> Option<f64> {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let n = s.len();
    (n > 0).then(|| if n % 2 == 1 { s[n / 2] } else { 0.5 * (s[n / 2 - 1] + s[n / 2]) })
}

/// Mean ± std of a share (0–1) as whole per cent: `"73 ± 5 %"`.
fn percent_text(rs: &[&CellResult], key: &str) -> String {
    let vals: Vec<f64> = rs.iter().filter_map(|r| r.metrics.get(key).copied().flatten()).map(|v| 100.0 * v).collect();
    mean_std(&vals).map_or("—".into(), |(m, s)| format!("{m:.0} ± {s:.0} %"))
}

/// Markdown: one row per method and view count, in the order the methods first appear: the
/// number of runs (cases), the median wall-clock of a run, and mean ± std of CD_ROI, HD95_ROI,
/// CD, missing-vessel recall and the centreline's recall and precision.
pub fn configurations_table(results: &[CellResult]) -> String {
    let mut methods: Vec<&str> = Vec::new();
    for r in results {
        if !methods.contains(&r.method.as_str()) {
            methods.push(&r.method);
        }
    }
    let counts: BTreeSet<usize> = results.iter().map(|r| r.views).collect();
    let mut md = String::from(
        "| configuration | views | runs | wall-clock per run (median) | CD_ROI (mm) | HD95_ROI (mm) | CD (mm) | \
         missing recall | centreline recall | centreline precision |\n\
         |---|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    for m in methods {
        for &v in &counts {
            let sel: Vec<&CellResult> = results.iter().filter(|r| r.method == m && r.views == v).collect();
            if sel.is_empty() {
                continue;
            }
            let seconds: Vec<f64> = sel.iter().map(|r| r.seconds).collect();
            let wall = median(&seconds).map_or("—".into(), |s| format!("{:.1} min", s / 60.0));
            md += &format!(
                "| {m} | {v} | {} | {wall} | {} | {} | {} | {} | {} | {} |\n",
                sel.len(),
                cell_text(&sel, "roi_cd_sum_mm"),
                cell_text(&sel, "roi_hd95_mm"),
                cell_text(&sel, "cd_sum_mm"),
                percent_text(&sel, "missing_recall"),
                percent_text(&sel, "centreline_recall"),
                percent_text(&sel, "centreline_precision"),
            );
        }
    }
    md
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A cell result with one metric (CD_ROI), for the tests here and of the experiment.
    pub(crate) fn result(case: &str, method: &str, views: usize, cd_roi: Option<f64>) -> CellResult {
        CellResult {
            case: case.into(),
            method: method.into(),
            views,
            view_list: "0,1".into(),
            prior: "case".into(),
            prior_threshold_mm: Some(1.0),
            seconds: 1.0,
            gaussians: 10,
            metrics: BTreeMap::from([("roi_cd_sum_mm".to_string(), cd_roi)]),
            config_hash: None,
            case_fingerprint: None,
            case_files: None,
        }
    }

    #[test]
    fn the_table_gives_mean_and_spread_over_cases_and_counts_undefined_cells() {
        let rs = [result("a", "full", 2, Some(2.0)), result("b", "full", 2, Some(4.0)), result("c", "full", 2, None)];
        let md = results_table(&rs, &["full".to_string()], &[2]);
        assert!(md.contains("| full | case | 3.00 ± 1.00 (1× ∞) |"), "{md}");
        let csv = results_csv(&rs);
        assert_eq!(csv.lines().count(), 4, "{csv}");
        assert!(csv.lines().nth(3).unwrap().ends_with(",inf"), "{csv}");
    }

    #[test]
    fn csv_fields_with_commas_or_quotes_are_quoted() {
        let rs = [result("case, left", "full \"x\"", 2, Some(2.0))];
        let line = results_csv(&rs).lines().nth(1).unwrap().to_string();
        assert!(line.starts_with("\"case, left\",\"full \"\"x\"\"\",2,\"0,1\",case,"), "{line}");
    }

    #[test]
    fn results_csv_reads_back_and_malformed_rows_name_the_line() {
        let mut rs = vec![result("case, left", "full \"x\"", 2, Some(2.5)), result("b", "full", 3, None)];
        rs[1].prior_threshold_mm = None;
        rs[1].seconds = 90.5;
        let path = Path::new("results.csv");
        let back = parse_results_csv(&results_csv(&rs), path).unwrap();
        assert_eq!(back, rs);
        let broken = results_csv(&rs).replace("90.5", "ninety");
        let err = parse_results_csv(&broken, path).unwrap_err().to_string();
        assert!(err.contains("results.csv") && err.contains("line 3") && err.contains("seconds"), "{err}");
        let err = parse_results_csv("a,b\n1,2\n", path).unwrap_err().to_string();
        assert!(err.contains("header"), "{err}");
    }

    #[test]
    fn the_configurations_table_has_one_row_per_method_and_view_count() {
        let mut rs = vec![
            result("a", "quick", 2, Some(2.0)),
            result("b", "quick", 2, Some(4.0)),
            result("a", "quick", 3, Some(1.0)),
            result("a", "cpu", 2, Some(3.0)),
        ];
        for (r, s) in rs.iter_mut().zip([60.0, 180.0, 90.0, 600.0]) {
            r.seconds = s;
            r.metrics.insert("missing_recall".into(), Some(0.5));
        }
        let md = configurations_table(&rs);
        let rows: Vec<&str> = md.lines().skip(2).collect();
        assert_eq!(rows.len(), 3, "{md}");
        assert!(rows[0].starts_with("| quick | 2 | 2 | 2.0 min | 3.00 ± 1.00 |"), "{md}");
        assert!(rows[1].starts_with("| quick | 3 | 1 | 1.5 min | 1.00 ± 0.00 |"), "{md}");
        assert!(rows[2].starts_with("| cpu | 2 | 1 | 10.0 min |") && rows[2].contains("| 50 ± 0 % |"), "{md}");
    }
}
