//! Which part of a sweep one process runs: `--shard i/n`, or `--shard auto` from the array job of
//! the scheduler it runs under (docs/cluster.md).
//!
//! How it works: a sweep's groups (α, trial) are dealt round-robin to n shards; shard i runs
//! groups g with g mod n = i. `auto` reads the index and count from the environment: a Slurm job
//! array (`SLURM_ARRAY_TASK_ID` less `SLURM_ARRAY_TASK_MIN`, divided by `SLURM_ARRAY_TASK_STEP`;
//! the count from `SLURM_ARRAY_TASK_COUNT`, else from `_MIN`/`_MAX`/`_STEP`), or a Kubernetes
//! Indexed Job (`JOB_COMPLETION_INDEX`; the count, the Job's `completions`, given as
//! `auto/N` since Kubernetes does not export it).

/// Which shard of the groups to run: `index` of `count` (0-based).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shard {
    pub index: usize,
    pub count: usize,
}

impl Default for Shard {
    fn default() -> Self {
        Self { index: 0, count: 1 }
    }
}

impl std::str::FromStr for Shard {
    type Err = String;
    /// `i/n` with 0 ≤ i < n.
    fn from_str(s: &str) -> Result<Self, String> {
        let (i, n) = s
            .split_once('/')
            .ok_or_else(|| format!("'{s}': expected i/n, e.g. 0/4"))?;
        let (index, count): (usize, usize) = (
            i.trim().parse().map_err(|_| format!("'{s}': bad shard index"))?,
            n.trim().parse().map_err(|_| format!("'{s}': bad shard count"))?,
        );
        if count == 0 || index >= count {
            return Err(format!("'{s}': the index must be in 0..n"));
        }
        Ok(Self { index, count })
    }
}

/// `--shard`: a fixed shard, or `auto` (optionally `auto/N`, the count) from the scheduler.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ShardSpec {
    Fixed(Shard),
    Auto { count: Option<usize> },
}

impl Default for ShardSpec {
    fn default() -> Self {
        Self::Fixed(Shard::default())
    }
}

impl std::str::FromStr for ShardSpec {
    type Err = String;
    /// `i/n`, `auto` or `auto/N`.
    fn from_str(s: &str) -> Result<Self, String> {
        match s.strip_prefix("auto") {
            Some("") => Ok(Self::Auto { count: None }),
            Some(rest) => {
                let n = rest
                    .strip_prefix('/')
                    .and_then(|n| n.trim().parse::<usize>().ok())
                    .filter(|n| *n > 0)
                    .ok_or_else(|| format!("'{s}': expected auto or auto/N with N ≥ 1"))?;
                Ok(Self::Auto { count: Some(n) })
            }
            None => s.parse().map(Self::Fixed),
        }
    }
}

impl ShardSpec {
    /// The shard to run, and where it came from, reading the environment through `var`.
    pub fn resolve(self, var: &dyn Fn(&str) -> Option<String>) -> Result<(Shard, String), String> {
        let count = match self {
            Self::Fixed(s) => return Ok((s, format!("--shard {}/{}", s.index, s.count))),
            Self::Auto { count } => count,
        };
        let num = |name: &str| -> Result<Option<usize>, String> {
            match var(name) {
                None => Ok(None),
                Some(v) if v.trim().is_empty() => Ok(None),
                Some(v) => v
                    .trim()
                    .parse()
                    .map(Some)
                    .map_err(|_| format!("{name}={v:?} is not a whole number")),
            }
        };
        let (index, found, from) = if let Some(id) = num("SLURM_ARRAY_TASK_ID")? {
            let min = num("SLURM_ARRAY_TASK_MIN")?.unwrap_or(0);
            let step = num("SLURM_ARRAY_TASK_STEP")?.unwrap_or(1).max(1);
            let from_range = num("SLURM_ARRAY_TASK_MAX")?
                .filter(|max| *max >= min)
                .map(|max| (max - min) / step + 1);
            let n = num("SLURM_ARRAY_TASK_COUNT")?.or(from_range);
            if id < min || (id - min) % step != 0 {
                return Err(format!(
                    "SLURM_ARRAY_TASK_ID {id} is not in the array's range from {min} by {step}: use a contiguous --array, e.g. 0-7"
                ));
            }
            (
                (id - min) / step,
                n,
                format!("Slurm array task {id} (SLURM_ARRAY_TASK_*)"),
            )
        } else if let Some(i) = num("JOB_COMPLETION_INDEX")? {
            (i, None, format!("Kubernetes Indexed Job completion index {i}"))
        } else {
            return Err(
                "--shard auto: neither SLURM_ARRAY_TASK_ID (a Slurm job array) nor JOB_COMPLETION_INDEX (a Kubernetes Indexed Job) is set: give --shard i/n"
                    .into(),
            );
        };
        let count = match (count, found) {
            (Some(given), Some(env)) if given != env => {
                return Err(format!(
                    "--shard auto/{given}, but the Slurm array has {env} tasks"
                ))
            }
            (Some(n), _) | (None, Some(n)) => n,
            (None, None) => {
                return Err(format!(
                    "--shard auto under {from}: the shard count is not in the environment: give --shard auto/N (N = the Job's completions)"
                ))
            }
        };
        if count == 0 || index >= count {
            return Err(format!("{from}: shard index {index} is not in 0..{count}"));
        }
        Ok((Shard { index, count }, format!("{from}: shard {index}/{count}")))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn resolve(spec: &str, vars: &[(&str, &str)]) -> Result<Shard, String> {
        let spec: ShardSpec = spec.parse()?;
        let get = |k: &str| vars.iter().find(|(n, _)| *n == k).map(|(_, v)| v.to_string());
        spec.resolve(&get).map(|(s, _)| s)
    }

    #[test]
    fn slurm_arrays_give_index_and_count() {
        let s = |index, count| Ok(Shard { index, count });
        // sbatch --array=0-7
        let v = [
            ("SLURM_ARRAY_TASK_ID", "3"),
            ("SLURM_ARRAY_TASK_COUNT", "8"),
            ("SLURM_ARRAY_TASK_MIN", "0"),
            ("SLURM_ARRAY_TASK_MAX", "7"),
        ];
        assert_eq!(resolve("auto", &v), s(3, 8));
        assert_eq!(resolve("auto/8", &v), s(3, 8));
        assert!(resolve("auto/4", &v).is_err());
        // --array=1-4: no count, the range says 4.
        let v = [
            ("SLURM_ARRAY_TASK_ID", "4"),
            ("SLURM_ARRAY_TASK_MIN", "1"),
            ("SLURM_ARRAY_TASK_MAX", "4"),
        ];
        assert_eq!(resolve("auto", &v), s(3, 4));
        // --array=0-6:2 → tasks 0, 2, 4, 6.
        let v = [
            ("SLURM_ARRAY_TASK_ID", "6"),
            ("SLURM_ARRAY_TASK_MIN", "0"),
            ("SLURM_ARRAY_TASK_MAX", "6"),
            ("SLURM_ARRAY_TASK_STEP", "2"),
        ];
        assert_eq!(resolve("auto", &v), s(3, 4));
        assert!(resolve("auto", &[("SLURM_ARRAY_TASK_ID", "x")]).is_err());
        assert!(resolve("auto", &[("SLURM_ARRAY_TASK_ID", "2")]).is_err());
    }

    #[test]
    fn indexed_jobs_need_the_count() {
        let v = [("JOB_COMPLETION_INDEX", "2")];
        assert_eq!(resolve("auto/5", &v), Ok(Shard { index: 2, count: 5 }));
        assert!(resolve("auto", &v).unwrap_err().contains("auto/N"));
        assert!(resolve("auto/2", &v).is_err());
        assert!(resolve("auto", &[]).unwrap_err().contains("SLURM_ARRAY_TASK_ID"));
        assert_eq!(resolve("1/3", &v), Ok(Shard { index: 1, count: 3 }));
        assert!("auto/0".parse::<ShardSpec>().is_err());
    }
}
