//! Delimited text: `x y z` per line, separated by commas, semicolons, tabs or spaces,
//! with an optional header. A header naming `x`, `y` and `z` picks those columns;
//! otherwise the first three are x, y, z. Other numeric columns are kept by name.

use super::{PointCloud, ReadError, err};

const F: &str = "CSV";

fn fields(line: &str) -> Vec<&str> {
    line.split(|c: char| c == ',' || c == ';' || c.is_whitespace())
        .filter(|s| !s.is_empty())
        .collect()
}

/// Read delimited text.
pub fn read(bytes: &[u8]) -> Result<PointCloud, ReadError> {
    let text = std::str::from_utf8(bytes).map_err(|_| err(F, "the file is not text (UTF-8)"))?;
    let mut cloud = PointCloud::default();
    let mut columns: Option<[usize; 3]> = None;
    let mut names: Vec<String> = Vec::new();
    let mut width = None;
    for (i, raw) in text.lines().enumerate() {
        let line = raw.trim();
        if line.is_empty() || line.starts_with('#') || line.starts_with("//") {
            continue;
        }
        let f = fields(line);
        let nums: Result<Vec<f64>, _> = f.iter().map(|s| s.parse::<f64>()).collect();
        let v = match nums {
            Ok(v) => v,
            Err(_) if cloud.points.is_empty() && width.is_none() && names.is_empty() => {
                // A header line.
                names = f
                    .iter()
                    .map(|s| s.trim_matches('"').to_ascii_lowercase())
                    .collect();
                let pos = |n: &str| names.iter().position(|c| c == n);
                if let (Some(x), Some(y), Some(z)) = (pos("x"), pos("y"), pos("z")) {
                    columns = Some([x, y, z]);
                }
                continue;
            }
            Err(_) => {
                return Err(err(
                    F,
                    format!("line {}: `{line}` is not a row of numbers", i + 1),
                ));
            }
        };
        let [cx, cy, cz] = columns.unwrap_or([0, 1, 2]);
        let need = cx.max(cy).max(cz) + 1;
        if v.len() < need {
            return Err(err(
                F,
                format!(
                    "line {}: {} values, at least {need} expected (x, y, z)",
                    i + 1,
                    v.len()
                ),
            ));
        }
        match width {
            None => {
                width = Some(v.len());
                for c in 0..v.len() {
                    if c != cx && c != cy && c != cz {
                        let name = names
                            .get(c)
                            .cloned()
                            .unwrap_or_else(|| format!("column{}", c + 1));
                        cloud.extra.push((name, Vec::new()));
                    }
                }
            }
            Some(w) if w != v.len() => {
                return Err(err(
                    F,
                    format!("line {}: {} values, the first row had {w}", i + 1, v.len()),
                ));
            }
            _ => {}
        }
        cloud.points.push([v[cx], v[cy], v[cz]]);
        let mut e = 0;
        for (c, val) in v.iter().enumerate() {
            if c != cx && c != cy && c != cz {
                cloud.extra[e].1.push(*val);
                e += 1;
            }
        }
    }
    Ok(cloud)
}
