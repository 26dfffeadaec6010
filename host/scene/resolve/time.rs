//! `[time]`: the end time, the step rule, the integrator and the output schedule.
use super::{err, non_negative, positive, VResult, MAX_FIXED_STEPS};
use crate::scene::file::*;
use crate::scene::model::*;

/// (`MAX_FIXED_STEPS` bounds a fixed step's count: `time.dt = 1e-300` would never end.)
pub(super) fn time(t: &TimeSection) -> VResult<Time> {
    positive("time.t_end", t.t_end)?;
    let integrator = t.integrator.unwrap_or(Integrator::FirstOrder);
    let position_update = t.position_update.unwrap_or(PositionUpdate::New);
    if integrator == Integrator::Kdk && position_update == PositionUpdate::Old {
        return err(
            "time.position_update",
            "\"old\" belongs to the first-order step; time.integrator = \"kdk\" drifts with v^{n+1/2}",
        );
    }
    let step = match (t.dt, t.cfl) {
        (Some(_), Some(_)) => {
            return err(
                "time.dt",
                "give either time.dt (fixed) or time.cfl, not both",
            )
        }
        (None, None) => return err("time.dt", "give time.dt (fixed step) or time.cfl"),
        (Some(dt), None) => {
            positive("time.dt", dt)?;
            let steps = (t.t_end / dt).ceil();
            if steps.is_nan() || steps > MAX_FIXED_STEPS {
                return err(
                    "time.dt",
                    format!(
                        "{steps:e} steps of {dt:e} to time.t_end = {}: more than {MAX_FIXED_STEPS:e}; \
                         a larger time.dt or time.cfl",
                        t.t_end
                    ),
                );
            }
            StepRule::Fixed { dt }
        }
        (None, Some(c)) => {
            positive("time.cfl", c)?;
            if c > 1.0 {
                return err("time.cfl", format!("must be ≤ 1 (got {c})"));
            }
            if let Some(m) = t.dt_max {
                positive("time.dt_max", m)?;
            }
            StepRule::Cfl {
                cfl: c,
                dt_max: t.dt_max,
            }
        }
    };
    if t.dt.is_some() && t.dt_max.is_some() {
        return err(
            "time.dt_max",
            "caps the CFL step (time.cfl); with a fixed time.dt there is nothing to cap",
        );
    }
    Ok(Time {
        t_end: t.t_end,
        step,
        output: output_schedule(t)?,
        position_update,
        integrator,
    })
}

fn output_schedule(t: &TimeSection) -> VResult<OutputSchedule> {
    match (&t.output_dt, &t.output_times) {
        (Some(_), Some(_)) => err("time.output_dt", "give output_dt or output_times, not both"),
        (Some(d), None) => {
            positive("time.output_dt", *d)?;
            if t.t_end / d > 100_000.0 {
                return err(
                    "time.output_dt",
                    format!(
                        "{} snapshots would be written (limit 100000)",
                        (t.t_end / d).floor()
                    ),
                );
            }
            Ok(OutputSchedule::Every { output_dt: *d })
        }
        (None, Some(ts)) => {
            if ts.len() > 100_000 {
                return err(
                    "time.output_times",
                    format!("{} snapshots would be written (limit 100000)", ts.len()),
                );
            }
            for (i, &x) in ts.iter().enumerate() {
                let key = format!("time.output_times.{i}");
                non_negative(&key, x)?;
                if x > t.t_end {
                    return err(key, format!("{x} is after time.t_end = {}", t.t_end));
                }
            }
            Ok(OutputSchedule::At {
                output_times: ts.clone(),
            })
        }
        (None, None) => Ok(OutputSchedule::EndOnly),
    }
}
