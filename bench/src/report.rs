//! Results of the benchmarks: one [`Measure`] per headline figure, the
//! summary table and the final JSON line; the banner every benchmark
//! starts with.

use serde_json::{Value, json};

/// What a figure must reach.
#[derive(Debug, Clone, Copy)]
pub enum Target {
    /// At least this value (throughput).
    AtLeast(f64),
    /// Strictly below this value (latency, memory).
    Below(f64),
}

impl Target {
    fn met(self, value: f64) -> bool {
        match self {
            Target::AtLeast(t) => value >= t,
            Target::Below(t) => value < t,
        }
    }

    /// The target for people, e.g. `>= 1,000,000 frames/s`.
    pub fn describe(self, unit: &str) -> String {
        match self {
            Target::AtLeast(t) => format!(">= {} {unit}", human(t)),
            Target::Below(t) => format!("< {} {unit}", human(t)),
        }
    }

    /// The value the target compares with.
    pub fn reference(self) -> f64 {
        match self {
            Target::AtLeast(t) | Target::Below(t) => t,
        }
    }

    fn to_json(self) -> Value {
        match self {
            Target::AtLeast(t) => json!({ "at_least": t }),
            Target::Below(t) => json!({ "below": t }),
        }
    }
}

/// The outcome of one measure.
#[derive(Debug, Clone)]
pub enum Outcome {
    /// Measured.
    Value(f64),
    /// Not measured, with the reason (e.g. the server binary is not built).
    Skipped(String),
    /// The benchmark failed to run.
    Error(String),
}

/// One headline figure with its target.
#[derive(Debug, Clone)]
pub struct Measure {
    /// Benchmark (subcommand) name.
    pub bench: &'static str,
    /// What is measured, for the table.
    pub label: &'static str,
    /// Unit of the value and the target.
    pub unit: &'static str,
    /// The target.
    pub target: Target,
    /// The result.
    pub outcome: Outcome,
    /// Secondary figures (JSON object).
    pub details: Value,
}

/// Pass/fail state of a measure.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    /// Target met.
    Pass,
    /// Target missed.
    Fail,
    /// Not measured.
    Skip,
    /// The benchmark did not run.
    Error,
}

impl Verdict {
    fn as_str(self) -> &'static str {
        match self {
            Verdict::Pass => "pass",
            Verdict::Fail => "FAIL",
            Verdict::Skip => "skip",
            Verdict::Error => "ERROR",
        }
    }
}

impl Measure {
    /// A figure with its outcome, whatever it is.
    pub fn new(
        bench: &'static str,
        label: &'static str,
        unit: &'static str,
        target: Target,
        outcome: Outcome,
        details: Value,
    ) -> Self {
        Measure {
            bench,
            label,
            unit,
            target,
            outcome,
            details,
        }
    }

    /// A measured figure.
    pub fn value(
        bench: &'static str,
        label: &'static str,
        value: f64,
        unit: &'static str,
        target: Target,
        details: Value,
    ) -> Self {
        Measure::new(bench, label, unit, target, Outcome::Value(value), details)
    }

    /// Pass, fail, skip or error.
    pub fn verdict(&self) -> Verdict {
        match &self.outcome {
            Outcome::Value(v) if self.target.met(*v) => Verdict::Pass,
            Outcome::Value(_) => Verdict::Fail,
            Outcome::Skipped(_) => Verdict::Skip,
            Outcome::Error(_) => Verdict::Error,
        }
    }

    fn result_text(&self) -> String {
        match &self.outcome {
            Outcome::Value(v) => format!("{} {}", human(*v), self.unit),
            Outcome::Skipped(why) => format!("skipped: {why}"),
            Outcome::Error(e) => format!("error: {e}"),
        }
    }

    /// The measure as JSON.
    pub fn to_json(&self) -> Value {
        let (value, note) = match &self.outcome {
            Outcome::Value(v) => (json!(v), Value::Null),
            Outcome::Skipped(s) | Outcome::Error(s) => (Value::Null, json!(s)),
        };
        json!({
            "bench": self.bench,
            "measure": self.label,
            "value": value,
            "unit": self.unit,
            "target": self.target.to_json(),
            "verdict": self.verdict().as_str().to_lowercase(),
            "note": note,
            "details": self.details,
        })
    }
}

/// A number with thousands separators (integers) or 3 significant decimals.
pub fn human(v: f64) -> String {
    if v.abs() >= 1000.0 {
        let n = v.round() as i64;
        let digits = n.unsigned_abs().to_string();
        let mut out = String::new();
        for (i, c) in digits.chars().enumerate() {
            if i > 0 && (digits.len() - i).is_multiple_of(3) {
                out.push(',');
            }
            out.push(c);
        }
        if n < 0 { format!("-{out}") } else { out }
    } else if v.abs() >= 100.0 {
        format!("{v:.0}")
    } else if v.abs() >= 10.0 {
        format!("{v:.1}")
    } else {
        format!("{v:.3}")
    }
}

/// `debug` or `release`: which build produced the figures (a debug build's
/// are no measure of the gateway).
pub fn build_profile() -> &'static str {
    if cfg!(debug_assertions) {
        "debug"
    } else {
        "release"
    }
}

/// The first line of a benchmark binary's output: its name, the build and
/// whether the counts are the `--quick` smoke run's, e.g.
/// `axis_bench (release build, full)`.
pub fn banner(bench: &str, quick: bool) -> String {
    format!(
        "{bench} ({} build, {})",
        build_profile(),
        if quick { "quick" } else { "full" }
    )
}

/// Prints the summary table.
pub fn print_table(measures: &[Measure]) {
    let rows: Vec<[String; 4]> = measures
        .iter()
        .map(|m| {
            [
                m.label.to_string(),
                m.result_text(),
                m.target.describe(m.unit),
                m.verdict().as_str().to_string(),
            ]
        })
        .collect();
    let header = ["measure", "result", "target", "pass/fail"];
    let mut widths = header.map(str::len);
    for r in &rows {
        for (w, c) in widths.iter_mut().zip(r) {
            *w = (*w).max(c.chars().count());
        }
    }
    let line = |cells: [&str; 4]| {
        let mut s = String::new();
        for (i, (c, w)) in cells.iter().zip(widths).enumerate() {
            if i > 0 {
                s.push_str(" | ");
            }
            s.push_str(&format!("{c:<w$}"));
        }
        println!("{}", s.trim_end());
    };
    println!();
    line(header);
    let rule: Vec<String> = widths.iter().map(|w| "-".repeat(*w)).collect();
    println!("{}", rule.join("-+-"));
    for r in &rows {
        line([&r[0], &r[1], &r[2], &r[3]]);
    }
    println!();
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn human_numbers() {
        assert_eq!(human(1_234_567.4), "1,234,567");
        assert_eq!(human(999.0), "999");
        assert_eq!(human(12.345), "12.3");
        assert_eq!(human(0.1234), "0.123");
        assert_eq!(human(-4321.0), "-4,321");
    }

    #[test]
    fn verdicts() {
        let m = |v, t| Measure::value("b", "l", v, "u", t, Value::Null).verdict();
        assert_eq!(m(10.0, Target::AtLeast(10.0)), Verdict::Pass);
        assert_eq!(m(9.0, Target::AtLeast(10.0)), Verdict::Fail);
        assert_eq!(m(10.0, Target::Below(10.0)), Verdict::Fail);
        assert_eq!(m(9.0, Target::Below(10.0)), Verdict::Pass);
    }
}
