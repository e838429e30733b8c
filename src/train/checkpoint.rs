//! What the trainers (stage 1 and the refiner) share to save and resume a run: a checkpoint's
//! tensors put back into it, and the loss-curve CSV written whole and cut
//! at a checkpoint's step.

use std::path::Path;

use candle_core::Tensor;
use candle_nn::VarMap;

use crate::io::IoError;

/// Sets every variable of `varmap` to the tensor of its name; the first missing or misshapen one
/// is the error.
pub fn restore_varmap(varmap: &VarMap, get: impl Fn(&str) -> Option<Tensor>) -> Result<(), String> {
    let data = varmap
        .data()
        .lock()
        .map_err(|_| "variable map lock poisoned".to_string())?;
    for (name, var) in data.iter() {
        let t = get(name).ok_or_else(|| format!("tensor {name} missing"))?;
        var.set(&t).map_err(|e| format!("tensor {name}: {e}"))?;
    }
    Ok(())
}

/// Writes a loss curve (header, then one row per step) atomically.
pub fn write_loss_csv(path: &Path, header: &str, rows: &[String]) -> Result<(), IoError> {
    let mut csv = String::from(header);
    csv.push('\n');
    for r in rows {
        csv.push_str(r);
        csv.push('\n');
    }
    crate::io::write_atomic(path, csv.as_bytes())
}

/// The rows of a loss-curve CSV (header skipped) whose step, the first column, is before `step`:
/// what a resumed run keeps (rows written after its checkpoint belong to the lost run).
pub fn loss_rows_before(csv: &Path, step: u64) -> Vec<String> {
    std::fs::read_to_string(csv)
        .unwrap_or_default()
        .lines()
        .skip(1)
        .filter(|l| {
            l.split(',')
                .next()
                .and_then(|s| s.parse::<u64>().ok())
                .is_some_and(|s| s < step)
        })
        .map(str::to_string)
        .collect()
}
