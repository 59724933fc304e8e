//! Pareto fronts of the dynamic λ sweep (eq. 3.18): the momentum residual
//! ‖K_m f − b_m‖ against the stress residual ‖K_s f − b_s‖, one point per λ, with
//! the chosen knee. CSV columns: `lambda,stress_residual,momentum_residual,knee`
//! (knee 1 on the chosen row, 0 elsewhere).

use super::chart::{Chart, Scale, PALETTE};
use crate::error::{Error, Result};
use image::RgbImage;
use std::path::Path;

#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct ParetoPoint {
    pub lambda: f64,
    pub stress_residual: f64,
    pub momentum_residual: f64,
}

/// Writes the front atomically (temporary file, then rename); `knee` indexes `points`.
pub fn write_pareto_csv(path: &Path, points: &[ParetoPoint], knee: Option<usize>) -> Result<()> {
    crate::scene::write_file_atomically(path, pareto_csv(points, knee)?.as_bytes())
}

/// The text [`write_pareto_csv`] writes.
pub fn pareto_csv(points: &[ParetoPoint], knee: Option<usize>) -> Result<String> {
    if let Some(k) = knee {
        if k >= points.len() {
            return Err(Error::Invalid(format!(
                "knee index {k} is outside the {} points of the front",
                points.len()
            )));
        }
    }
    let mut text = String::from("lambda,stress_residual,momentum_residual,knee\n");
    for (i, p) in points.iter().enumerate() {
        text.push_str(&format!(
            "{},{},{},{}\n",
            p.lambda,
            p.stress_residual,
            p.momentum_residual,
            u8::from(knee == Some(i))
        ));
    }
    Ok(text)
}

/// Reads a front written by [`write_pareto_csv`] (columns in any order, `knee`
/// optional). Errors name the file, line and column.
pub fn read_pareto_csv(path: &Path) -> Result<(Vec<ParetoPoint>, Option<usize>)> {
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut reader = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .comment(Some(b'#'))
        .from_reader(std::io::BufReader::new(file));
    let located = |e: csv::Error| {
        let line = e.position().map(|p| p.line() as usize);
        Error::data(path, line, None, e.to_string())
    };
    let headers = reader.headers().map_err(located)?.clone();
    let column = |name: &str| headers.iter().position(|h| h == name);
    let required = |name: &str| {
        column(name).ok_or_else(|| {
            Error::data(
                path,
                Some(1),
                Some(name),
                format!("required column `{name}` is missing from the header"),
            )
        })
    };
    let lambda_col = required("lambda")?;
    let stress_col = required("stress_residual")?;
    let momentum_col = required("momentum_residual")?;
    let knee_col = column("knee");

    let mut points = Vec::new();
    let mut knee: Option<(usize, usize)> = None;
    for record in reader.records() {
        let record = record.map_err(located)?;
        let line = record.position().map(|p| p.line() as usize).unwrap_or(0);
        if record.iter().all(str::is_empty) {
            continue;
        }
        let number = |i: usize, name: &str| -> Result<f64> {
            let text = record.get(i).unwrap_or("");
            let value: f64 = text.parse().map_err(|_| {
                Error::data(
                    path,
                    Some(line),
                    Some(name),
                    format!("`{text}` is not a number"),
                )
            })?;
            if !value.is_finite() || value < 0.0 {
                return Err(Error::data(
                    path,
                    Some(line),
                    Some(name),
                    format!("`{text}` must be a finite number ≥ 0"),
                ));
            }
            Ok(value)
        };
        points.push(ParetoPoint {
            lambda: number(lambda_col, "lambda")?,
            stress_residual: number(stress_col, "stress_residual")?,
            momentum_residual: number(momentum_col, "momentum_residual")?,
        });
        if let Some(i) = knee_col {
            match record.get(i).unwrap_or("") {
                "" | "0" => {}
                "1" => {
                    if let Some((_, first_line)) = knee {
                        return Err(Error::data(
                            path,
                            Some(line),
                            Some("knee"),
                            format!("a second knee; line {first_line} is already marked"),
                        ));
                    }
                    knee = Some((points.len() - 1, line));
                }
                other => {
                    return Err(Error::data(
                        path,
                        Some(line),
                        Some("knee"),
                        format!("`{other}` is not 0 or 1"),
                    ))
                }
            }
        }
    }
    Ok((points, knee.map(|(i, _)| i)))
}

/// The front on log–log axes (momentum residual against stress residual), a few
/// points labelled with their λ, the knee marked. Points with a zero residual
/// cannot sit on log axes and are left out of the drawing.
pub fn draw_pareto(points: &[ParetoPoint], knee: Option<usize>) -> RgbImage {
    pareto_chart(points, knee).render()
}

/// The chart [`draw_pareto`] renders, for callers that want to add to it.
pub fn pareto_chart(points: &[ParetoPoint], knee: Option<usize>) -> Chart {
    let xy: Vec<(f64, f64)> = points
        .iter()
        .map(|p| (p.stress_residual, p.momentum_residual))
        .collect();
    let mut chart = Chart::new(900, 620)
        .title("Pareto front of the λ sweep")
        .x_axis("stress residual ‖K_s f − b_s‖", Scale::Log)
        .y_axis("momentum residual ‖K_m f − b_m‖", Scale::Log)
        .line("", &xy, PALETTE[0])
        .scatter("", &xy, PALETTE[0]);
    // Label about five points spread along the front, plus both ends.
    let n = points.len();
    let every = n.div_ceil(5).max(1);
    for (i, p) in points.iter().enumerate() {
        if Some(i) == knee {
            continue;
        }
        if i % every == 0 || i + 1 == n {
            chart = chart.note(
                p.stress_residual,
                p.momentum_residual,
                &format!("λ={}", format_lambda(p.lambda)),
            );
        }
    }
    if let Some(p) = knee.and_then(|k| points.get(k)) {
        chart = chart.mark(
            p.stress_residual,
            p.momentum_residual,
            &format!("knee λ={}", format_lambda(p.lambda)),
        );
    }
    chart
}

/// λ with three significant digits.
fn format_lambda(lambda: f64) -> String {
    if lambda == 0.0 {
        return "0".into();
    }
    let magnitude = lambda.abs().log10().floor() as i32;
    if (-3..4).contains(&magnitude) {
        let decimals = (2 - magnitude).max(0) as usize;
        format!("{:.*}", decimals, lambda)
    } else {
        format!("{:.2e}", lambda)
    }
}
