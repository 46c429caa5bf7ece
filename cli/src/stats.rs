//! The statistics of timed runs that `nmat bench`, `nmat bench-train`, `nmat walk` and the
//! benchmark binaries report: one median for all of them.

use std::time::Instant;

/// The middle value after sorting (of an even count, the upper of the two middle values, so
/// that every reported value is one that was measured); NaN when there are none.
pub fn median(values: impl IntoIterator<Item = f64>) -> f64 {
    let mut v: Vec<f64> = values.into_iter().collect();
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

/// The median seconds of `runs` calls of `f`, stopping at its first error.
pub fn median_seconds<E>(runs: usize, mut f: impl FnMut() -> Result<(), E>) -> Result<f64, E> {
    let mut seconds = Vec::with_capacity(runs);
    for _ in 0..runs {
        let start = Instant::now();
        f()?;
        seconds.push(start.elapsed().as_secs_f64());
    }
    Ok(median(seconds))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_median_is_a_measured_value() {
        assert_eq!(median([3.0, 1.0, 2.0]), 2.0);
        // Even count: the upper middle value, not the mean of the two (2.5).
        assert_eq!(median([4.0, 1.0, 3.0, 2.0]), 3.0);
        assert_eq!(median([7.5]), 7.5);
        assert!(median([]).is_nan());
    }

    #[test]
    fn median_seconds_runs_f_the_given_times_and_stops_at_an_error() {
        let mut calls = 0;
        let s = median_seconds(3, || -> Result<(), ()> {
            calls += 1;
            Ok(())
        });
        assert!(s.is_ok_and(|s| s >= 0.0));
        assert_eq!(calls, 3);
        let mut calls = 0;
        let e = median_seconds(5, || {
            calls += 1;
            if calls == 2 { Err("second") } else { Ok(()) }
        });
        assert_eq!((e, calls), (Err("second"), 2));
    }
}
