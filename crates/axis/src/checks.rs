//! Argument checks shared by the axis controllers: the same command is
//! refused with the same words whichever drive family backs the axis.

use crate::{AxisCommand, CommandError};

/// `v` must be a finite number.
pub(crate) fn finite(name: &str, v: f64) -> Result<(), CommandError> {
    if v.is_finite() {
        Ok(())
    } else {
        Err(CommandError::BadValue(format!(
            "{name} must be a finite number"
        )))
    }
}

/// An optional velocity or acceleration: positive and at most `max`.
fn optional_limit(name: &str, v: Option<f64>, max: f64) -> Result<(), CommandError> {
    if let Some(v) = v {
        finite(name, v)?;
        if v <= 0.0 {
            return Err(CommandError::BadValue(format!(
                "{name} must be positive (0 = the axis default), got {v}"
            )));
        }
        if v > max {
            return Err(CommandError::AboveMaximum(format!(
                "{name} {v} exceeds the axis maximum {max}"
            )));
        }
    }
    Ok(())
}

/// The numeric arguments of a Move or Jog against the axis's maxima
/// (other commands have none).
pub(crate) fn motion_arguments(
    cmd: &AxisCommand,
    max_velocity: f64,
    max_acceleration: f64,
    unit: &str,
) -> Result<(), CommandError> {
    match *cmd {
        AxisCommand::Move {
            target,
            velocity,
            acceleration,
            ..
        } => {
            finite("target", target)?;
            optional_limit(&format!("velocity ({unit}/s)"), velocity, max_velocity)?;
            optional_limit(
                &format!("acceleration ({unit}/s²)"),
                acceleration,
                max_acceleration,
            )
        }
        AxisCommand::Jog {
            velocity,
            acceleration,
        } => {
            finite("velocity", velocity)?;
            if velocity.abs() > max_velocity {
                return Err(CommandError::AboveMaximum(format!(
                    "jog velocity {velocity} {unit}/s exceeds the axis maximum {max_velocity}"
                )));
            }
            optional_limit(
                &format!("acceleration ({unit}/s²)"),
                acceleration,
                max_acceleration,
            )
        }
        _ => Ok(()),
    }
}

/// A target within the soft limits.
pub(crate) fn soft_limits(
    target: f64,
    min: Option<f64>,
    max: Option<f64>,
    unit: &str,
) -> Result<(), CommandError> {
    if let Some(max) = max
        && target > max
    {
        return Err(CommandError::BeyondSoftLimit(format!(
            "target {target} {unit} is beyond the soft limit max_position = {max} {unit}"
        )));
    }
    if let Some(min) = min
        && target < min
    {
        return Err(CommandError::BeyondSoftLimit(format!(
            "target {target} {unit} is beyond the soft limit min_position = {min} {unit}"
        )));
    }
    Ok(())
}
