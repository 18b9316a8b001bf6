//! `cangate gen BUS`: generated load, like can-utils' cangen: identifiers,
//! lengths and payloads random, incrementing or fixed, one frame every
//! `-g` milliseconds (0: as fast as the gateway takes them), until `-n`
//! frames or Ctrl-C. Sent through one Attach stream, so the gateway's
//! per-client raw frame budget and bus share apply and every refusal is
//! counted (see [`super::bus_writer`]).

use super::bus_writer::{BATCH, BusWriter};
use super::{App, Failure, Result, ctrl_c, hex_bytes};
use cangate_client::can::{CanId, Frame};
use clap::Args;
use tokio::time::{Duration, Instant};

/// `cangate gen BUS …`
#[derive(Args, Debug)]
pub(crate) struct GenArgs {
    /// Bus name.
    bus: String,
    /// Milliseconds between frames (fractions allowed; 0: as fast as the
    /// gateway takes them).
    #[arg(short = 'g', long = "gap", value_name = "MS", default_value_t = 200.0,
          value_parser = super::finite)]
    gap_ms: f64,
    /// Identifiers: r random, i incrementing, or a fixed hex identifier.
    #[arg(short = 'I', long = "id", value_name = "MODE", default_value = "r",
          value_parser = Pattern::parse_id)]
    id: Pattern<u32>,
    /// Payload lengths: r random, i incrementing, or a fixed length in
    /// bytes (for CAN FD one of 0-8, 12, 16, 20, 24, 32, 48, 64). Default:
    /// r.
    #[arg(short = 'L', long = "len", value_name = "MODE",
          value_parser = Pattern::parse_len)]
    len: Option<Pattern<u8>>,
    /// Payloads: r random, i a little-endian frame counter, or fixed hex
    /// bytes (then they set the length: no -L).
    #[arg(short = 'D', long = "data", value_name = "MODE", default_value = "r",
          value_parser = Pattern::parse_data)]
    data: Pattern<Vec<u8>>,
    /// Extended (29-bit) identifiers.
    #[arg(short = 'e', long)]
    extended: bool,
    /// CAN FD frames (the bus must be an FD bus).
    #[arg(short = 'f', long)]
    fd: bool,
    /// CAN FD frames with bit rate switch (implies -f).
    #[arg(short = 'b', long)]
    brs: bool,
    /// Remote requests instead of data frames.
    #[arg(short = 'R', long, conflicts_with_all = ["fd", "brs", "data"])]
    remote: bool,
    /// Stop after N frames.
    #[arg(short = 'n', value_name = "N")]
    count: Option<u64>,
    /// Seed of the random choices, for a sequence that can be repeated.
    #[arg(long)]
    seed: Option<u64>,
}

/// How one field of the frames varies.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Pattern<T> {
    /// Chosen at random for each frame.
    Random,
    /// Counting up from zero, wrapping.
    Increment,
    /// The same for every frame.
    Fixed(T),
}

impl Pattern<u32> {
    fn parse_id(text: &str) -> Result<Self, String> {
        Pattern::parse(text, |t| {
            u32::from_str_radix(t.trim_start_matches("0x"), 16)
                .ok()
                .filter(|id| *id <= 0x1FFF_FFFF)
                .ok_or_else(|| format!("{t:?} is not r, i or a hex identifier"))
        })
    }
}

impl Pattern<u8> {
    fn parse_len(text: &str) -> Result<Self, String> {
        Pattern::parse(text, |t| {
            t.parse::<u8>()
                .ok()
                .filter(|n| *n <= 64)
                .ok_or_else(|| format!("{t:?} is not r, i or a length 0..=64"))
        })
    }
}

impl Pattern<Vec<u8>> {
    fn parse_data(text: &str) -> Result<Self, String> {
        Pattern::parse(text, |t| {
            hex_bytes(t).and_then(|d| {
                if d.len() <= 64 {
                    Ok(d)
                } else {
                    Err(format!("{t:?}: at most 64 bytes"))
                }
            })
        })
    }
}

impl<T> Pattern<T> {
    fn parse(text: &str, fixed: impl Fn(&str) -> Result<T, String>) -> Result<Self, String> {
        match text {
            "r" => Ok(Pattern::Random),
            "i" => Ok(Pattern::Increment),
            t => fixed(t).map(Pattern::Fixed),
        }
    }
}

/// The payload lengths a CAN FD frame can have (DLC 0..=15).
const FD_LENGTHS: [u8; 16] = [0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64];

/// Makes the frames, one after the other.
pub(crate) struct Generator {
    args: GenSpec,
    rng: fastrand::Rng,
    counter: u64,
}

/// What [`Generator`] makes (the frame-shaping part of [`GenArgs`]).
#[derive(Debug, Clone)]
pub(crate) struct GenSpec {
    pub(crate) id: Pattern<u32>,
    pub(crate) len: Pattern<u8>,
    pub(crate) data: Pattern<Vec<u8>>,
    pub(crate) extended: bool,
    pub(crate) fd: bool,
    pub(crate) brs: bool,
    pub(crate) remote: bool,
}

impl GenSpec {
    /// Input the frames cannot be made from, refused before connecting.
    pub(crate) fn check(&self) -> Result<(), String> {
        let max_id = if self.extended { 0x1FFF_FFFF } else { 0x7FF };
        if let Pattern::Fixed(id) = self.id
            && id > max_id
        {
            return Err(format!(
                "identifier {id:X} is above {max_id:X} (-e for extended identifiers)"
            ));
        }
        let lengths: &[u8] = if self.fd {
            &FD_LENGTHS
        } else {
            &FD_LENGTHS[..9]
        };
        let fixed_len = match (&self.len, &self.data) {
            (Pattern::Fixed(n), _) => Some(*n),
            (_, Pattern::Fixed(d)) => Some(d.len() as u8),
            _ => None,
        };
        if let Some(n) = fixed_len
            && !lengths.contains(&n)
        {
            return Err(format!(
                "a {} frame cannot carry {n} bytes (lengths: {lengths:?})",
                if self.fd { "CAN FD" } else { "classic CAN" }
            ));
        }
        Ok(())
    }
}

impl Generator {
    pub(crate) fn new(spec: GenSpec, seed: Option<u64>) -> Generator {
        Generator {
            args: spec,
            rng: seed.map_or_else(fastrand::Rng::new, fastrand::Rng::with_seed),
            counter: 0,
        }
    }

    /// The next frame.
    pub(crate) fn next_frame(&mut self) -> Frame {
        let n = self.counter;
        self.counter += 1;
        let a = &self.args;
        let max_id: u32 = if a.extended { 0x1FFF_FFFF } else { 0x7FF };
        let raw = match a.id {
            Pattern::Random => self.rng.u32(0..=max_id),
            Pattern::Increment => (n % (u64::from(max_id) + 1)) as u32,
            Pattern::Fixed(id) => id,
        };
        let id = CanId::new(raw, a.extended).expect("identifier within range");
        let lengths: &[u8] = if a.fd { &FD_LENGTHS } else { &FD_LENGTHS[..9] };
        let len = match (&a.data, &a.len) {
            (Pattern::Fixed(d), _) => d.len() as u8,
            (_, Pattern::Random) => lengths[self.rng.usize(..lengths.len())],
            (_, Pattern::Increment) => lengths[(n % lengths.len() as u64) as usize],
            (_, Pattern::Fixed(l)) => *l,
        };
        if a.remote {
            return Frame::new_remote(id, len).expect("length checked");
        }
        let data: Vec<u8> = match &a.data {
            Pattern::Random => (0..len).map(|_| self.rng.u8(..)).collect(),
            Pattern::Increment => {
                let mut d = n.to_le_bytes().to_vec();
                d.resize(usize::from(len), 0);
                d
            }
            Pattern::Fixed(d) => d.clone(),
        };
        if a.fd {
            Frame::new_fd(id, &data, a.brs, false).expect("length checked")
        } else {
            Frame::new(id, &data).expect("length checked")
        }
    }
}

impl GenArgs {
    fn spec(&self) -> GenSpec {
        GenSpec {
            id: self.id.clone(),
            len: self.len.clone().unwrap_or(Pattern::Random),
            data: self.data.clone(),
            extended: self.extended,
            fd: self.fd || self.brs,
            brs: self.brs,
            remote: self.remote,
        }
    }
}

/// `cangate gen BUS …`
pub(crate) async fn generate(app: &App, a: GenArgs) -> Result<()> {
    let spec = a.spec();
    if a.len.is_some() && matches!(a.data, Pattern::Fixed(_)) {
        return Err(Failure::usage(
            "gen",
            "fixed data (-D HEX) sets the length: no -L with it",
        ));
    }
    spec.check().map_err(|why| Failure::usage("gen", why))?;
    let writer = BusWriter::open(app, &a.bus).await?;
    if spec.fd && !writer.fd() {
        return Err(Failure::usage(
            "gen",
            format!("{} is not a CAN FD bus: no -f/-b", a.bus),
        ));
    }
    let mut frames = Generator::new(spec, a.seed);
    let gap = Duration::from_secs_f64(a.gap_ms.max(0.0) / 1000.0);
    let sending = async {
        let start = Instant::now();
        let mut made = 0u64;
        let mut batch = Vec::with_capacity(BATCH);
        while a.count.is_none_or(|n| made < n) {
            // Every frame due by now goes in one batch; then wait for the
            // next one's time.
            let due_now = if gap.is_zero() {
                BATCH as u64
            } else {
                let elapsed = start.elapsed().as_nanos() / gap.as_nanos().max(1);
                (elapsed as u64 + 1)
                    .saturating_sub(made)
                    .clamp(1, BATCH as u64)
            };
            let room = a.count.map_or(due_now, |n| due_now.min(n - made));
            batch.clear();
            batch.extend((0..room).map(|_| frames.next_frame()));
            made += room;
            writer.send(&batch).await?;
            if !gap.is_zero() {
                tokio::time::sleep_until(start + gap.mul_f64(made as f64)).await;
            }
        }
        Ok::<(), Failure>(())
    };
    let result = tokio::select! {
        r = sending => r,
        _ = ctrl_c() => Ok(()),
    };
    let tally = writer.finish().await;
    eprintln!("cangate: gen on {}: {}", a.bus, tally.summary());
    result?;
    if !tally.complete() {
        return Err(Failure::failed(
            format!("gen on {}", a.bus),
            "not every frame went out (see the summary above)",
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec() -> GenSpec {
        GenSpec {
            id: Pattern::Random,
            len: Pattern::Random,
            data: Pattern::Random,
            extended: false,
            fd: false,
            brs: false,
            remote: false,
        }
    }

    #[test]
    fn increments_count_from_zero_and_wrap() {
        let mut g = Generator::new(
            GenSpec {
                id: Pattern::Increment,
                len: Pattern::Increment,
                data: Pattern::Increment,
                ..spec()
            },
            None,
        );
        let texts: Vec<String> = (0..10).map(|_| g.next_frame().to_string()).collect();
        assert_eq!(
            texts,
            [
                "000#",
                "001#01",
                "002#0200",
                "003#030000",
                "004#04000000",
                "005#0500000000",
                "006#060000000000",
                "007#07000000000000",
                "008#0800000000000000",
                "009#"
            ]
        );
        g.counter = 0x7FF;
        assert_eq!(g.next_frame().id().raw(), 0x7FF);
        assert_eq!(g.next_frame().id().raw(), 0);
    }

    #[test]
    fn random_frames_stay_valid_and_repeat_with_a_seed() {
        for fd in [false, true] {
            for extended in [false, true] {
                let s = GenSpec {
                    fd,
                    extended,
                    brs: fd,
                    ..spec()
                };
                let mut a = Generator::new(s.clone(), Some(7));
                let mut b = Generator::new(s, Some(7));
                for _ in 0..2000 {
                    let f = a.next_frame();
                    assert_eq!(f, b.next_frame());
                    assert_eq!(f.is_fd(), fd);
                    assert_eq!(f.is_extended(), extended);
                    assert!(FD_LENGTHS.contains(&(f.data().len() as u8)));
                    assert!(fd || f.data().len() <= 8);
                }
            }
        }
    }

    #[test]
    fn fixed_fields_are_kept_and_impossible_ones_refused() {
        let mut g = Generator::new(
            GenSpec {
                id: Pattern::Fixed(0x123),
                data: Pattern::Fixed(vec![0xDE, 0xAD]),
                ..spec()
            },
            None,
        );
        assert_eq!(g.next_frame().to_string(), "123#DEAD");
        let remote = GenSpec {
            id: Pattern::Fixed(0x10),
            len: Pattern::Fixed(3),
            remote: true,
            ..spec()
        };
        assert_eq!(
            Generator::new(remote, None).next_frame().to_string(),
            "010#R3"
        );
        assert!(
            GenSpec {
                id: Pattern::Fixed(0x800),
                ..spec()
            }
            .check()
            .is_err()
        );
        assert!(
            GenSpec {
                id: Pattern::Fixed(0x800),
                extended: true,
                ..spec()
            }
            .check()
            .is_ok()
        );
        assert!(
            GenSpec {
                len: Pattern::Fixed(9),
                ..spec()
            }
            .check()
            .is_err()
        );
        assert!(
            GenSpec {
                len: Pattern::Fixed(12),
                fd: true,
                ..spec()
            }
            .check()
            .is_ok()
        );
        assert!(
            GenSpec {
                len: Pattern::Fixed(13),
                fd: true,
                ..spec()
            }
            .check()
            .is_err()
        );
        assert!(
            GenSpec {
                data: Pattern::Fixed(vec![0; 9]),
                ..spec()
            }
            .check()
            .is_err()
        );
    }

    #[test]
    fn patterns_parse_like_cangens() {
        assert_eq!(Pattern::parse_id("r"), Ok(Pattern::Random));
        assert_eq!(Pattern::parse_id("i"), Ok(Pattern::Increment));
        assert_eq!(Pattern::parse_id("7DF"), Ok(Pattern::Fixed(0x7DF)));
        assert!(Pattern::parse_id("xyz").is_err());
        assert!(Pattern::parse_id("20000000").is_err());
        assert_eq!(Pattern::parse_len("8"), Ok(Pattern::Fixed(8)));
        assert!(Pattern::parse_len("65").is_err());
        assert_eq!(
            Pattern::parse_data("DEAD"),
            Ok(Pattern::Fixed(vec![0xDE, 0xAD]))
        );
        assert!(Pattern::parse_data(&"00".repeat(65)).is_err());
    }
}
