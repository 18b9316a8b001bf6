//! Every decoder fed by the network or a file survives arbitrary input: the
//! committed fuzz seeds (valid inputs and every crash the fuzzers found),
//! mutations of them and random bytes, through the same entry functions the
//! cargo-fuzz targets call (`fuzz/harness`). The long runs are `cargo fuzz`
//! (see fuzz/README.md); this is the quick check in the ordinary test run.

use std::path::{Path, PathBuf};

use cangate_fuzz_harness::TARGETS;

/// Mutated and random inputs per target, on top of the seeds: fewer for
/// the whole-file targets, whose inputs are kilobytes (and, for the
/// configuration, load several EDS each).
fn generated(target: &str) -> usize {
    match target {
        "eds" | "config" => 150,
        _ => 1500,
    }
}

fn seeds_dir(target: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../fuzz/seeds")
        .join(target)
}

fn seeds(target: &str) -> Vec<(String, Vec<u8>)> {
    let dir = seeds_dir(target);
    let mut out: Vec<_> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|entry| {
            let path = entry.expect("directory entry").path();
            let bytes = std::fs::read(&path).expect("seed file");
            (path.display().to_string(), bytes)
        })
        .collect();
    out.sort();
    out
}

/// xorshift64*: fixed seeds, so a failure replays exactly.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

/// A mutation of `base` the way libFuzzer mutates: flip bits, overwrite
/// bytes with interesting values, insert, delete, duplicate a slice, or
/// splice in part of another seed.
fn mutate(rng: &mut Rng, base: &[u8], other: &[u8]) -> Vec<u8> {
    let mut v = base.to_vec();
    for _ in 0..=rng.below(4) {
        let at = rng.below(v.len() + 1);
        match rng.below(6) {
            0 if !v.is_empty() => {
                let i = at.min(v.len() - 1);
                v[i] ^= 1 << rng.below(8);
            }
            1 if !v.is_empty() => {
                let i = at.min(v.len() - 1);
                v[i] = [0, 1, 0x7F, 0x80, 0xFF, b'#', b'=', b'\n', b'['][rng.below(9)];
            }
            2 => {
                let n = rng.below(8);
                for _ in 0..n {
                    v.insert(at, rng.next() as u8);
                }
            }
            3 if !v.is_empty() => {
                let end = (at + rng.below(16)).min(v.len());
                v.drain(at.min(end)..end);
            }
            4 if !v.is_empty() => {
                let start = rng.below(v.len());
                let end = (start + rng.below(32)).min(v.len());
                let piece = v[start..end].to_vec();
                v.splice(at..at, piece);
            }
            _ if !other.is_empty() => {
                let start = rng.below(other.len());
                let end = (start + rng.below(64)).min(other.len());
                v.splice(at..at, other[start..end].iter().copied());
            }
            _ => {}
        }
    }
    v
}

#[test]
fn every_target_has_seeds() {
    for (name, _) in TARGETS {
        assert!(
            !seeds(name).is_empty(),
            "fuzz/seeds/{name} holds no seed: the target would start from nothing"
        );
    }
}

#[test]
fn seeds_mutations_and_random_inputs_never_panic() {
    for (name, run) in TARGETS {
        let started = std::time::Instant::now();
        let seeds = seeds(name);
        for (path, bytes) in &seeds {
            let result = std::panic::catch_unwind(|| run(bytes));
            assert!(result.is_ok(), "{name}: seed {path} panics");
        }
        let mut rng = Rng(0x9E37_79B9_7F4A_7C15 ^ name.len() as u64);
        for i in 0..generated(name) {
            let input = if i % 4 == 3 || seeds.is_empty() {
                let n = rng.below(96);
                (0..n).map(|_| rng.next() as u8).collect()
            } else {
                let base = &seeds[rng.below(seeds.len())].1;
                let other = &seeds[rng.below(seeds.len())].1;
                mutate(&mut rng, base, other)
            };
            let result = std::panic::catch_unwind(|| run(&input));
            assert!(
                result.is_ok(),
                "{name}: generated input #{i} panics; replay it with \
                 `cargo +nightly fuzz run {name} <file>` after saving these bytes: {input:02X?}"
            );
        }
        eprintln!(
            "{name}: {} inputs in {:?}",
            seeds.len() + generated(name),
            started.elapsed()
        );
    }
}
