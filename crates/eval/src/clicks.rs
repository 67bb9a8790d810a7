//! The published click files: `img0,img1,uv_clicked,uv_groundtruth`, the last
//! two cells JSON lists of `[u, v]` pixel pairs, one list entry per click.

use serde::{Deserialize, Serialize};

use crate::EvalError;

/// One row of a click file: pixels clicked in `img0` and where each truly lies
/// in `img1` (pixels, as in the file).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ClickPair {
    pub img0: String,
    pub img1: String,
    pub uv_clicked: Vec<[f64; 2]>,
    pub uv_groundtruth: Vec<[f64; 2]>,
    /// The file it came from and its data row (1-based, header excluded).
    pub source: String,
    pub row: usize,
}

/// A row that could not be read, with the reason.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MalformedRow {
    pub source: String,
    pub row: usize,
    pub reason: String,
}

/// A parsed click file: the rows that could be read and those that could not.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct PointsCsv {
    pub pairs: Vec<ClickPair>,
    pub malformed: Vec<MalformedRow>,
}

const COLUMNS: [&str; 4] = ["img0", "img1", "uv_clicked", "uv_groundtruth"];

/// Parses a click file. `source` names it in messages. A missing column is
/// an error; a malformed row (wrong cell count, bad JSON, lists of unequal
/// length or empty) is skipped, logged as a warning naming file and row, and
/// counted in [`PointsCsv::malformed`]. Accepts CRLF, a UTF-8 BOM, quoted
/// cells, extra columns in any order.
pub fn parse_points_csv(text: &str, source: &str) -> Result<PointsCsv, EvalError> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut reader = csv::ReaderBuilder::new().flexible(true).trim(csv::Trim::All).from_reader(text.as_bytes());
    let headers = reader
        .headers()
        .map_err(|e| EvalError::BadFile { source_name: source.to_owned(), reason: format!("header: {e}") })?
        .clone();
    let mut index = [0usize; 4];
    for (slot, column) in index.iter_mut().zip(COLUMNS) {
        *slot = headers.iter().position(|h| h == column).ok_or_else(|| EvalError::BadFile {
            source_name: source.to_owned(),
            reason: format!("no column {column:?} in the header (expected {})", COLUMNS.join(",")),
        })?;
    }
    let mut parsed = PointsCsv::default();
    for (i, record) in reader.records().enumerate() {
        let row = i + 1;
        let result = record.map_err(|e| e.to_string()).and_then(|record| parse_row(&record, index, source, row));
        match result {
            Ok(pair) => parsed.pairs.push(pair),
            Err(reason) => {
                tracing::warn!("{source}: row {row}: skipped: {reason}");
                parsed.malformed.push(MalformedRow { source: source.to_owned(), row, reason });
            }
        }
    }
    Ok(parsed)
}

fn parse_row(record: &csv::StringRecord, index: [usize; 4], source: &str, row: usize) -> Result<ClickPair, String> {
    let cell = |k: usize| {
        let column = COLUMNS.get(k).copied().unwrap_or("?");
        index.get(k).and_then(|&i| record.get(i)).ok_or_else(|| format!("{} cells, no {column:?}", record.len()))
    };
    let (img0, img1) = (cell(0)?, cell(1)?);
    if img0.is_empty() || img1.is_empty() {
        return Err("empty image name".to_owned());
    }
    let uv_clicked = parse_uv_list(cell(2)?).map_err(|e| format!("uv_clicked: {e}"))?;
    let uv_groundtruth = parse_uv_list(cell(3)?).map_err(|e| format!("uv_groundtruth: {e}"))?;
    if uv_clicked.len() != uv_groundtruth.len() {
        return Err(format!("{} clicked points but {} ground-truth points", uv_clicked.len(), uv_groundtruth.len()));
    }
    if uv_clicked.is_empty() {
        return Err("no clicked points".to_owned());
    }
    Ok(ClickPair {
        img0: img0.to_owned(),
        img1: img1.to_owned(),
        uv_clicked,
        uv_groundtruth,
        source: source.to_owned(),
        row,
    })
}

/// `[[u, v], ...]`; a lone `[u, v]` is read as one point.
fn parse_uv_list(cell: &str) -> Result<Vec<[f64; 2]>, String> {
    match serde_json::from_str::<Vec<[f64; 2]>>(cell) {
        Ok(list) => Ok(list),
        Err(list_error) => match serde_json::from_str::<[f64; 2]>(cell) {
            Ok(single) => Ok(vec![single]),
            Err(_) => Err(format!("not a JSON list of [u, v] pairs ({list_error}): {cell:?}")),
        },
    }
}

/// Writes click pairs in the published format (JSON lists quoted as needed).
pub fn write_points_csv(pairs: &[ClickPair]) -> String {
    let mut writer = csv::WriterBuilder::new().from_writer(Vec::new());
    let mut rows: Vec<[String; 4]> = vec![COLUMNS.map(str::to_owned)];
    for pair in pairs {
        let json = |uv: &Vec<[f64; 2]>| serde_json::to_string(uv).unwrap_or_else(|_| "[]".to_owned());
        rows.push([pair.img0.clone(), pair.img1.clone(), json(&pair.uv_clicked), json(&pair.uv_groundtruth)]);
    }
    for row in rows {
        // Writing to a Vec cannot fail.
        let _ = writer.write_record(&row);
    }
    let bytes = writer.into_inner().unwrap_or_default();
    String::from_utf8(bytes).unwrap_or_default()
}
