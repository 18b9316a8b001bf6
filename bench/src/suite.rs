//! `cangate-bench report`: every benchmark in one go and one table of
//! their headline figures with targets, ratios and pass/fail.
//!
//! The in-process benchmarks (`all`) run here; the benchmark binaries
//! (`sdo_bench`, `unary_bench`, `axis_bench --scale`, `wheel_bench`,
//! `cansmc_bench`) run as child processes from the directory of this
//! executable, each with its own output shown as it comes, and the table
//! is built from the JSON line each prints last. A binary that is not built, or fails, is a row
//! saying so; the others still run.

use crate::report::{Measure, Outcome, Verdict};
use serde_json::Value;
use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};

/// One line of the summary table.
#[derive(Debug, Clone, PartialEq)]
pub struct Row {
    /// What is measured.
    pub measure: String,
    /// The figure, with its unit.
    pub result: String,
    /// The target.
    pub target: String,
    /// The figure against its reference or target (`×`), where one is.
    pub ratio: String,
    /// pass, FAIL, skip, ERROR, or "-" (reported, not judged).
    pub verdict: String,
}

impl Row {
    fn judged(measure: String, result: String, target: String, ratio: String, pass: bool) -> Row {
        Row {
            measure,
            result,
            target,
            ratio,
            verdict: if pass { "pass" } else { "FAIL" }.into(),
        }
    }

    fn failed(measure: &str, why: String) -> Row {
        Row {
            measure: measure.into(),
            result: why,
            target: String::new(),
            ratio: String::new(),
            verdict: "ERROR".into(),
        }
    }

    /// True for rows that count against the run.
    pub fn is_failure(&self) -> bool {
        self.verdict == "FAIL" || self.verdict == "ERROR"
    }
}

/// Rows of the in-process benchmarks' measures.
pub fn measure_rows(measures: &[Measure]) -> Vec<Row> {
    measures
        .iter()
        .map(|m| {
            let (result, ratio) = match &m.outcome {
                Outcome::Value(v) => (
                    format!("{} {}", crate::report::human(*v), m.unit),
                    format!("{:.2}× target", v / m.target.reference()),
                ),
                Outcome::Skipped(why) => (format!("skipped: {why}"), String::new()),
                Outcome::Error(e) => (format!("error: {e}"), String::new()),
            };
            Row {
                measure: m.label.to_string(),
                result,
                target: m.target.describe(m.unit),
                ratio,
                verdict: match m.verdict() {
                    Verdict::Pass => "pass",
                    Verdict::Fail => "FAIL",
                    Verdict::Skip => "skip",
                    Verdict::Error => "ERROR",
                }
                .into(),
            }
        })
        .collect()
}

/// Runs benchmark binary `name` (beside this executable) with `args`,
/// echoing its output, and returns the JSON object of its last line.
pub fn run_bin(name: &str, args: &[&str]) -> Result<Value, String> {
    let exe = std::env::current_exe().map_err(|e| format!("cannot find this executable: {e}"))?;
    let path = exe.with_file_name(name);
    if !path.exists() {
        return Err(format!(
            "{} is not built (cargo build --release -p cangate-bench --bins)",
            path.display()
        ));
    }
    println!("\n### {name} {}", args.join(" "));
    let mut child = Command::new(&path)
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .map_err(|e| format!("cannot run {}: {e}", path.display()))?;
    let out = child.stdout.take().ok_or("no stdout")?;
    let mut last_json = None;
    for line in BufReader::new(out).lines().map_while(Result::ok) {
        if line.starts_with('{') {
            last_json = serde_json::from_str::<Value>(&line).ok();
        } else {
            println!("{line}");
        }
    }
    let status = child.wait().map_err(|e| format!("{name}: {e}"))?;
    match last_json {
        Some(v) => Ok(v),
        None => Err(format!("{name} printed no result ({status})")),
    }
}

fn f(v: &Value) -> Option<f64> {
    v.as_f64()
}

/// `sdo_bench`'s own checks (it judges them: python reference in the same
/// run, bus ceiling).
pub fn sdo_rows(v: &Value) -> Vec<Row> {
    let mut rows: Vec<Row> = v["checks"]
        .as_array()
        .into_iter()
        .flatten()
        .map(|c| Row {
            measure: format!("SDO: {}", c["name"].as_str().unwrap_or("?")),
            result: c["value"].as_str().unwrap_or("?").into(),
            target: c["target"].as_str().unwrap_or("").into(),
            ratio: String::new(),
            verdict: match c["verdict"].as_str() {
                Some("ok") => "pass".into(),
                Some("MISSED") => "FAIL".into(),
                _ => "-".into(),
            },
        })
        .collect();
    if let Some(why) = v["reference"]["skipped"].as_str() {
        rows.push(Row {
            measure: "SDO: python canopen reference".into(),
            result: format!("skipped: {why}"),
            target: String::new(),
            ratio: String::new(),
            verdict: "skip".into(),
        });
    }
    rows
}

/// `axis_bench --scale`: CPU of 6 CSP axes and the cost per axis at 6, 12
/// and 24 axes.
pub fn axis_rows(v: &Value) -> Vec<Row> {
    let mut rows = Vec::new();
    if let (Some(gw), Some(target)) = (
        f(&v["cpu_percent"]["gateway"]),
        f(&v["cpu_percent"]["target"]),
    ) {
        rows.push(Row::judged(
            "CPU, 6 CSP axes, 1 ms SYNC".into(),
            format!("{gw:.1} % of one core"),
            format!("< {target} %"),
            format!("{:.2}× target", gw / target),
            gw < target,
        ));
    }
    let scale = v["scale"].as_array().cloned().unwrap_or_default();
    let per = |i: usize| scale.get(i).and_then(|s| f(&s["per_axis_percent"]));
    for s in &scale {
        let (Some(n), Some(b), Some(p), Some(g)) = (
            s["axes"].as_u64(),
            s["buses"].as_u64(),
            f(&s["per_axis_percent"]),
            f(&s["gateway_percent"]),
        ) else {
            continue;
        };
        let ratio = per(0).map_or(String::new(), |p6| format!("{:.2}× per axis at 6", p / p6));
        rows.push(Row::judged(
            format!("CPU per CSP axis, {n} axes on {b} bus(es)"),
            format!("{p:.2} % ({g:.1} % in all)"),
            "<= 1 %".into(),
            ratio,
            p <= 1.0,
        ));
    }
    rows
}

/// `unary_bench`: the gateway's CPU per gRPC call that touches no bus
/// (reported: its target is against canopend, in `peer_bench`).
pub fn unary_rows(v: &Value) -> Vec<Row> {
    let (Some(cpu), Some(p50)) = (f(&v["server_cpu_us_per_call"]), f(&v["p50_us"])) else {
        return Vec::new();
    };
    vec![Row {
        measure: "gRPC unary call without bus (GetBus): gateway CPU per call".into(),
        result: format!("{cpu:.1} µs (round trip p50 {p50:.0} µs)"),
        target: "half canopend's ratio (peer_bench)".into(),
        ratio: String::new(),
        verdict: "-".into(),
    }]
}

/// `wheel_bench`: one feed subscriber's p99, and 100 subscribers' p99
/// against it (target ≤ 2×).
pub fn wheel_rows(v: &Value) -> Vec<Row> {
    let mut rows = Vec::new();
    let one = f(&v["one"]["p99_ms"]);
    if let Some(one) = one {
        rows.push(Row::judged(
            "handwheel feed, 1 subscriber, bus -> client p99".into(),
            format!("{one:.3} ms"),
            "< 1 ms".into(),
            format!("{:.2}× target", one),
            one < 1.0,
        ));
    }
    if let (Some(one), Some(many), Some(n)) = (
        one,
        f(&v["fanout"]["p99_ms"]),
        v["fanout"]["subscribers"].as_u64(),
    ) {
        let ratio = many / one;
        rows.push(Row::judged(
            format!("handwheel feed, {n} subscribers, p99"),
            format!("{many:.3} ms"),
            "<= 2× one subscriber's p99".into(),
            format!("{ratio:.2}× one"),
            ratio <= 2.0,
        ));
    }
    rows
}

/// `cansmc_bench`: MST start jitter and the cost per slave.
pub fn cansmc_rows(v: &Value) -> Vec<Row> {
    let mut rows = Vec::new();
    if let (Some(p99), Some(target)) = (
        f(&v["jitter_us"]["spin"]["p99"]),
        f(&v["jitter_us"]["target_p99"]),
    ) {
        rows.push(Row::judged(
            "CANsmc MST start lateness p99, 2 ms, 10 slaves".into(),
            format!("{p99:.0} µs"),
            format!("< {target} µs"),
            format!("{:.2}× target", p99 / target),
            p99 < target,
        ));
    }
    for s in v["scale"].as_array().into_iter().flatten() {
        let (Some(cycle), Some(n), Some(cpu), Some(per)) = (
            s["cycle_us"].as_u64(),
            s["slaves"].as_u64(),
            f(&s["cpu_percent"]),
            f(&s["per_slave_percent"]),
        ) else {
            continue;
        };
        rows.push(Row {
            measure: format!("CANsmc master CPU, {n} slaves at {} ms", cycle / 1000),
            result: format!("{cpu:.2} % ({per:.3} % per slave)"),
            target: "flat per slave".into(),
            ratio: String::new(),
            verdict: "-".into(),
        });
    }
    rows
}

/// The rows of one binary, or one row saying why there are none.
pub fn bin_rows(name: &str, args: &[&str], rows: fn(&Value) -> Vec<Row>) -> Vec<Row> {
    match run_bin(name, args) {
        Ok(v) => {
            let r = rows(&v);
            if r.is_empty() {
                vec![Row::failed(name, "no figures in its result".into())]
            } else {
                r
            }
        }
        Err(e) => vec![Row::failed(name, e)],
    }
}

/// Prints the table (markdown, so the README can hold it as it is).
pub fn print_rows(rows: &[Row]) {
    let header = ["measure", "result", "target", "ratio", "pass/fail"];
    let cells: Vec<[&str; 5]> = rows
        .iter()
        .map(|r| {
            [
                r.measure.as_str(),
                r.result.as_str(),
                r.target.as_str(),
                r.ratio.as_str(),
                r.verdict.as_str(),
            ]
        })
        .collect();
    println!();
    println!("| {} |", header.join(" | "));
    println!("|{}", " --- |".repeat(header.len()));
    for c in cells {
        println!("| {} |", c.join(" | "));
    }
    println!();
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn rows_of_each_benchmarks_json() {
        let axis = json!({"cpu_percent": {"gateway": 7.5, "target": 10.0},
            "scale": [{"axes": 6, "buses": 1, "gateway_percent": 9.0, "per_axis_percent": 1.5},
                      {"axes": 24, "buses": 4, "gateway_percent": 21.6, "per_axis_percent": 0.9}]});
        let r = axis_rows(&axis);
        assert_eq!(r.len(), 3);
        assert_eq!(r[0].verdict, "pass");
        assert_eq!(r[1].verdict, "FAIL");
        assert_eq!(r[2].ratio, "0.60× per axis at 6");
        assert_eq!(r[2].verdict, "pass");

        let wheel = json!({"one": {"p99_ms": 0.5}, "fanout": {"subscribers": 100, "p99_ms": 1.5}});
        let r = wheel_rows(&wheel);
        assert_eq!(r[1].ratio, "3.00× one");
        assert_eq!(r[1].verdict, "FAIL");

        let sdo = json!({"checks": [{"name": "n", "value": "1 µs", "target": "t", "verdict": "ok"},
                                    {"name": "m", "value": "2", "target": "t", "verdict": "MISSED"}],
                         "reference": {"skipped": "no python"}});
        let r = sdo_rows(&sdo);
        assert_eq!(
            r.iter().map(|r| r.verdict.as_str()).collect::<Vec<_>>(),
            ["pass", "FAIL", "skip"]
        );
        assert!(cansmc_rows(&json!({})).is_empty());
        assert!(Row::failed("x", "y".into()).is_failure());
    }
}
