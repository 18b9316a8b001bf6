//! `cangate sdo read|write`: typed SDO transfers (node ids, object
//! addresses and values are the library's types; the value keeps its CiA
//! 301 type in --json, the proto's `Value`).

use super::{App, Context, Failure, Result, hex, hex_bytes, node_id};
use cangate_client::{Client, DataType, NodeId, Object, SdoValue, pb};
use clap::{Args, Subcommand, ValueEnum};
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// `cangate sdo …`
#[derive(Args, Debug)]
pub(crate) struct SdoArgs {
    #[command(subcommand)]
    verb: SdoVerb,
}

#[derive(Subcommand, Debug)]
enum SdoVerb {
    /// Read an object: `cangate sdo read can0 1 0x1008 --type vs`,
    /// `cangate sdo read can0 1 "Manufacturer device name"`.
    Read {
        /// Bus.
        bus: String,
        /// Node id (1..=127).
        #[arg(value_parser = node_id)]
        node: NodeId,
        /// Object: INDEX[:SUB] in hex (0x1018:01, 1017), or its name in the
        /// node's EDS ("Producer heartbeat time", "Identity object.Serial
        /// number"; `cangate node objects` lists them).
        #[arg(value_parser = object)]
        object: Object,
        /// Decode as this type (default: the node's EDS type when the
        /// gateway knows it, else the bytes; `raw`: the bytes).
        #[arg(long = "type", short = 't')]
        ty: Option<TypeArg>,
        #[command(flatten)]
        transfer: Transfer,
        /// Write the bytes read to this file (domains, firmware images);
        /// shows the progress on standard error.
        #[arg(long, value_name = "FILE")]
        output: Option<PathBuf>,
    },
    /// Write an object: `cangate sdo write can0 1 0x607A i32 -5000`,
    /// `cangate sdo write can0 1 "Producer heartbeat time" 100`.
    Write {
        /// Bus.
        bus: String,
        /// Node id (1..=127).
        #[arg(value_parser = node_id)]
        node: NodeId,
        /// Object: INDEX[:SUB] in hex, or its name in the node's EDS.
        #[arg(value_parser = object)]
        object: Object,
        /// [TYPE] VALUE. TYPE: bool i8 i16 i32 i64 u8 u16 u32 u64 f32 f64
        /// vs us os domain, or raw (hex bytes as they are); leave it out
        /// when the node's EDS has the object (the gateway takes its
        /// type). VALUE: decimal or 0x hex for integers (negative ones as
        /// they are: -5000), true/false for bool, text for strings, hex
        /// bytes for os, domain and raw. With --file only TYPE, if any.
        #[arg(value_name = "[TYPE] VALUE", num_args = 0..=2, allow_hyphen_values = true)]
        words: Vec<String>,
        /// Take the bytes from this file (domains, firmware images).
        #[arg(long, value_name = "FILE")]
        file: Option<PathBuf>,
        #[command(flatten)]
        transfer: Transfer,
        /// Write even to the controlword, mode, targets or program objects
        /// of an enabled axis's drive (refused otherwise: the axis commands
        /// its drive).
        #[arg(long)]
        force: bool,
    },
}

impl SdoArgs {
    /// A value that does not fit its type, refused before connecting.
    pub(crate) fn check(&self) -> Result<()> {
        if let SdoVerb::Write {
            bus, words, file, ..
        } = &self.verb
        {
            let usage = |e| Failure::usage(format!("sdo write on {bus}"), e);
            if let (Some(ty), Some(text)) = type_and_value(words, file.is_some()).map_err(usage)? {
                let parsed = match ty {
                    TypeArg::Raw => hex_bytes(&text).map(|_| ()),
                    _ => parse_value(ty, &text).map(|_| ()),
                };
                parsed.map_err(usage)?;
            }
        }
        Ok(())
    }
}

/// The command line with the options of an `sdo write` that follow its
/// `[TYPE] VALUE` words moved before them (`sdo write can0 1 0x2100 domain
/// --file fw.bin --block` as `sdo write --file fw.bin --block can0 1 0x2100
/// domain`): the words take values that start with a dash (`-5000`,
/// `-x-`), so clap would take an option after them for a value. Only the
/// long options `sdo write` knows (its own and the global ones) move;
/// nothing after `--`.
pub(crate) fn hoist_write_options(args: Vec<std::ffi::OsString>) -> Vec<std::ffi::OsString> {
    use clap::CommandFactory;
    let Some(at) = args
        .windows(2)
        .position(|w| w[0] == "sdo" && w[1] == "write")
    else {
        return args;
    };
    let mut cli = super::Cli::command();
    cli.build();
    let globals = cli.get_arguments().filter(|a| a.is_global_set());
    let Some(write) = cli
        .find_subcommand("sdo")
        .and_then(|c| c.find_subcommand("write"))
    else {
        return args;
    };
    // Long option name -> whether it takes a value.
    let options: std::collections::HashMap<String, bool> = write
        .get_arguments()
        .chain(globals)
        .filter_map(|a| Some((a.get_long()?.to_string(), a.get_action().takes_values())))
        .chain([("help".to_string(), false)])
        .collect();
    let start = at + 2;
    let (mut hoisted, mut rest) = (Vec::new(), Vec::new());
    let mut tail = args[start..].iter();
    while let Some(arg) = tail.next() {
        if arg == "--" {
            rest.push(arg.clone());
            rest.extend(tail.by_ref().cloned());
            break;
        }
        let option = arg
            .to_str()
            .and_then(|a| a.strip_prefix("--"))
            .map(|a| {
                a.split_once('=')
                    .map_or((a, false), |(name, _)| (name, true))
            })
            .and_then(|(name, inline)| Some((*options.get(name)?, inline)));
        match option {
            Some((takes_value, inline)) => {
                hoisted.push(arg.clone());
                if takes_value
                    && !inline
                    && let Some(value) = tail.next()
                {
                    hoisted.push(value.clone());
                }
            }
            None => rest.push(arg.clone()),
        }
    }
    let mut out = args[..start].to_vec();
    out.extend(hoisted);
    out.extend(rest);
    out
}

/// The `[TYPE] VALUE` words of `sdo write` (only `[TYPE]` with a file).
/// A lone word is the value, unless it names a type: that is more likely
/// a forgotten value than a text to write (write it as `vs u8`).
fn type_and_value(
    words: &[String],
    file: bool,
) -> Result<(Option<TypeArg>, Option<String>), String> {
    let ty = |w: &str| {
        TypeArg::from_str(w, true).map_err(|_| {
            format!("{w:?} is not a type (bool i8 i16 i32 i64 u8 u16 u32 u64 f32 f64 vs us os domain raw)")
        })
    };
    match (words, file) {
        ([], true) => Ok((None, None)),
        ([t], true) => Ok((Some(ty(t)?), None)),
        (_, true) => Err("with --file give at most the type, not a value".into()),
        ([], false) => Err("give a value (or --file)".into()),
        ([v], false) => match TypeArg::from_str(v, true) {
            Ok(_) => Err(format!(
                "{v:?} is a type: give the value after it (to write the text {v:?}, give its type: vs {v})"
            )),
            Err(_) => Ok((None, Some(v.clone()))),
        },
        ([t, v], false) => Ok((Some(ty(t)?), Some(v.clone()))),
        _ => Err("give [TYPE] VALUE".into()),
    }
}

/// Transfer options.
#[derive(Args, Debug, Clone, Copy)]
struct Transfer {
    /// Use SDO block transfer (falls back to segmented).
    #[arg(long)]
    block: bool,
    /// The node's answer timeout in ms (default: the bus's, normally 500).
    #[arg(long, value_name = "MS", value_parser = clap::value_parser!(u32).range(1..=60_000))]
    sdo_timeout_ms: Option<u32>,
}

impl Transfer {
    fn to_pb(self) -> pb::SdoOptions {
        pb::SdoOptions {
            timeout_ms: self.sdo_timeout_ms.unwrap_or(0),
            block: self.block,
        }
    }

    /// The client for this transfer: no request bound for files (a long
    /// block transfer is bounded by the node's answers), and room for a
    /// longer SDO timeout than the request bound.
    fn client(self, client: &Client, file: bool) -> Client {
        if file {
            return client.with_request_timeout(None);
        }
        match (client.request_timeout(), self.sdo_timeout_ms) {
            (Some(bound), Some(sdo)) => {
                let need = Duration::from_millis(u64::from(sdo)) + Duration::from_secs(2);
                client.with_request_timeout(Some(bound.max(need)))
            }
            _ => client.clone(),
        }
    }
}

/// The CiA 301 types as typed on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum TypeArg {
    /// BOOLEAN.
    Bool,
    /// INTEGER8.
    I8,
    /// INTEGER16.
    I16,
    /// INTEGER32.
    I32,
    /// INTEGER64.
    I64,
    /// UNSIGNED8.
    U8,
    /// UNSIGNED16.
    U16,
    /// UNSIGNED32.
    U32,
    /// UNSIGNED64.
    U64,
    /// REAL32.
    F32,
    /// REAL64.
    F64,
    /// VISIBLE_STRING.
    Vs,
    /// UNICODE_STRING.
    Us,
    /// OCTET_STRING (hex bytes).
    Os,
    /// DOMAIN (hex bytes).
    Domain,
    /// No type: the bytes as they are.
    Raw,
}

impl TypeArg {
    fn data_type(self) -> DataType {
        match self {
            TypeArg::Bool => DataType::Boolean,
            TypeArg::I8 => DataType::Integer8,
            TypeArg::I16 => DataType::Integer16,
            TypeArg::I32 => DataType::Integer32,
            TypeArg::I64 => DataType::Integer64,
            TypeArg::U8 => DataType::Unsigned8,
            TypeArg::U16 => DataType::Unsigned16,
            TypeArg::U32 => DataType::Unsigned32,
            TypeArg::U64 => DataType::Unsigned64,
            TypeArg::F32 => DataType::Real32,
            TypeArg::F64 => DataType::Real64,
            TypeArg::Vs => DataType::VisibleString,
            TypeArg::Us => DataType::UnicodeString,
            TypeArg::Os => DataType::OctetString,
            TypeArg::Domain => DataType::Domain,
            TypeArg::Raw => DataType::Unspecified,
        }
    }
}

/// An address (`0x1018:01`, `1017`: text starting with a digit) or an
/// EDS name (anything else), see [`Object`]'s `FromStr`.
fn object(text: &str) -> Result<Object, String> {
    text.parse::<Object>().map_err(|e| match e {
        cangate_client::Error::InvalidInput { message } => message,
        other => other.to_string(),
    })
}

/// The request fields `(index, subindex, object)` of an object.
fn fields(object: &Object) -> (u32, u32, String) {
    match object {
        Object::Address(a) => (a.index.into(), a.sub.into(), String::new()),
        Object::Name(n) => (0, 0, n.clone()),
    }
}

/// An integer as typed: decimal (signed) or 0x hex.
fn integer(text: &str) -> Result<i128, String> {
    let t = text.trim();
    let (neg, digits) = match t.strip_prefix('-') {
        Some(rest) => (true, rest),
        None => (false, t.strip_prefix('+').unwrap_or(t)),
    };
    let v = match digits
        .strip_prefix("0x")
        .or_else(|| digits.strip_prefix("0X"))
    {
        Some(h) => i128::from_str_radix(h, 16),
        None => digits.parse::<i128>(),
    }
    .map_err(|_| format!("{text:?} is not an integer"))?;
    Ok(if neg { -v } else { v })
}

/// The value typed on the command line as `ty`.
fn parse_value(ty: TypeArg, text: &str) -> Result<SdoValue, String> {
    let fits = |name: &str| format!("{text} does not fit {name}");
    macro_rules! int {
        ($t:ty, $v:ident, $name:literal) => {
            <$t>::try_from(integer(text)?)
                .map(SdoValue::$v)
                .map_err(|_| fits($name))
        };
    }
    match ty {
        TypeArg::Bool => match text.to_ascii_lowercase().as_str() {
            "1" | "true" | "on" | "yes" => Ok(SdoValue::Bool(true)),
            "0" | "false" | "off" | "no" => Ok(SdoValue::Bool(false)),
            _ => Err(format!("{text:?} is not a boolean (true/false, 1/0)")),
        },
        TypeArg::I8 => int!(i8, I8, "INTEGER8"),
        TypeArg::I16 => int!(i16, I16, "INTEGER16"),
        TypeArg::I32 => int!(i32, I32, "INTEGER32"),
        TypeArg::I64 => int!(i64, I64, "INTEGER64"),
        TypeArg::U8 => int!(u8, U8, "UNSIGNED8"),
        TypeArg::U16 => int!(u16, U16, "UNSIGNED16"),
        TypeArg::U32 => int!(u32, U32, "UNSIGNED32"),
        TypeArg::U64 => int!(u64, U64, "UNSIGNED64"),
        TypeArg::F32 | TypeArg::F64 => {
            let v: f64 = text
                .trim()
                .parse()
                .map_err(|_| format!("{text:?} is not a number"))?;
            Ok(if ty == TypeArg::F32 {
                SdoValue::F32(v as f32)
            } else {
                SdoValue::F64(v)
            })
        }
        TypeArg::Vs => Ok(SdoValue::VisibleString(text.to_string())),
        TypeArg::Us => Ok(SdoValue::UnicodeString(text.to_string())),
        TypeArg::Os => hex_bytes(text).map(SdoValue::OctetString),
        TypeArg::Domain | TypeArg::Raw => hex_bytes(text).map(SdoValue::Domain),
    }
}

/// Shows the progress of the running transfer of `node` on standard error
/// (ListSdoTransfers every 100 ms) until aborted.
fn progress_bar(client: &Client, bus: &str, node: NodeId) -> tokio::task::JoinHandle<()> {
    let client = client.with_request_timeout(Some(Duration::from_secs(2)));
    let bus = bus.to_string();
    let node = u32::from(node);
    tokio::spawn(async move {
        let started = Instant::now();
        loop {
            tokio::time::sleep(Duration::from_millis(100)).await;
            let req = pb::ListSdoTransfersRequest { bus: bus.clone() };
            let Ok(r) = client
                .call(
                    "ListSdoTransfers",
                    None,
                    client.canopen_client().list_sdo_transfers(req),
                )
                .await
            else {
                continue;
            };
            let Some(t) = r.transfers.into_iter().find(|t| t.node == node) else {
                continue;
            };
            let rate = t.transferred as f64 / 1e3 / started.elapsed().as_secs_f64().max(1e-6);
            let line = match t.total {
                Some(total) if total > 0 => {
                    let pct = t.transferred as f64 * 100.0 / total as f64;
                    let bar = "#".repeat((pct / 5.0) as usize);
                    format!(
                        "[{bar:<20}] {pct:5.1} %  {} / {} bytes  {rate:.1} kB/s  ({})",
                        t.transferred, total, t.protocol
                    )
                }
                _ => format!("{} bytes  {rate:.1} kB/s  ({})", t.transferred, t.protocol),
            };
            eprint!("\r{line}   ");
        }
    })
}

/// Runs `call` with a progress bar on standard error when `file`.
async fn with_progress<T>(
    app: &App,
    file: bool,
    bus: &str,
    node: NodeId,
    call: impl Future<Output = T>,
) -> T {
    let bar = super::AbortOnDrop(file.then(|| progress_bar(&app.client, bus, node)));
    let r = call.await;
    if bar.0.is_some() {
        drop(bar);
        eprintln!();
    }
    r
}

fn rate(bytes: usize, elapsed: Duration) -> String {
    format!(
        "{bytes} bytes in {:.1} ms ({:.1} kB/s)",
        elapsed.as_secs_f64() * 1e3,
        bytes as f64 / 1e3 / elapsed.as_secs_f64().max(1e-9)
    )
}

/// `cangate sdo …`
pub(crate) async fn run(app: &App, args: SdoArgs) -> Result<()> {
    match args.verb {
        SdoVerb::Read {
            bus,
            node,
            object,
            ty,
            transfer,
            output,
        } => {
            let what = format!("sdo read on {bus}");
            let (index, subindex, object) = fields(&object);
            let req = pb::ReadSdoRequest {
                bus: bus.clone(),
                node: node.into(),
                index,
                subindex,
                r#type: ty.map_or(DataType::Unspecified, TypeArg::data_type) as i32,
                options: Some(transfer.to_pb()),
                object,
            };
            let mut client = transfer.client(&app.client, output.is_some());
            let started = Instant::now();
            let mut r = with_progress(app, output.is_some(), &bus, node, client.read_sdo(req))
                .await
                .ctx(what.clone())?;
            if ty == Some(TypeArg::Raw) {
                // Raw asks for the bytes: the request has no type then, and
                // the gateway decodes with the EDS's, which is not shown.
                r.value = None;
            }
            if let Some(path) = &output {
                std::fs::write(path, &r.raw).ctx(format!("writing {}", path.display()))?;
                eprintln!(
                    "{} written to {}",
                    rate(r.raw.len(), started.elapsed()),
                    path.display()
                );
                return if app.json {
                    super::print_json(&r)
                } else {
                    Ok(())
                };
            }
            let text = match &r.value {
                Some(v) => {
                    SdoValue::from_pb(v).map_or_else(|_| hex(&r.raw, " "), |v| v.to_string())
                }
                None => hex(&r.raw, " "),
            };
            app.show(text, &r)
        }
        SdoVerb::Write {
            bus,
            node,
            object,
            words,
            file,
            transfer,
            force,
        } => {
            let what = format!("sdo write on {bus}");
            let usage = |e| Failure::usage(what.clone(), e);
            let (ty, value) = type_and_value(&words, file.is_some()).map_err(usage)?;
            let data = match (&file, ty, value) {
                (Some(path), _, _) => pb::write_sdo_request::Data::Raw(
                    std::fs::read(path).ctx(format!("reading {}", path.display()))?,
                ),
                (None, Some(TypeArg::Raw), Some(text)) => {
                    pb::write_sdo_request::Data::Raw(hex_bytes(&text).map_err(usage)?)
                }
                (None, Some(ty), Some(text)) => pb::write_sdo_request::Data::Value(
                    parse_value(ty, &text).map_err(usage)?.to_pb(),
                ),
                // No type: the gateway parses the text as the EDS type.
                (None, None, Some(text)) => pb::write_sdo_request::Data::Value(pb::Value {
                    r#type: DataType::Unspecified as i32,
                    value: Some(pb::value::Value::StringValue(text)),
                }),
                (None, _, None) => return Err(usage("give a value or --file".into())),
            };
            let (index, subindex, object) = fields(&object);
            let req = pb::WriteSdoRequest {
                bus: bus.clone(),
                node: node.into(),
                index,
                subindex,
                data: Some(data),
                options: Some(transfer.to_pb()),
                object,
                force,
            };
            let mut client = transfer.client(&app.client, file.is_some());
            let started = Instant::now();
            let r = with_progress(app, file.is_some(), &bus, node, client.write_sdo(req))
                .await
                .ctx(what)?;
            if file.is_some() && !app.json {
                eprintln!("{} written", rate(r.bytes as usize, started.elapsed()));
            }
            if app.json {
                super::print_json(&r)?;
            }
            Ok(())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::{Cli, Command};
    use super::*;
    use cangate_client::ObjectAddress;
    use clap::Parser;

    fn sdo(argv: &[&str]) -> SdoVerb {
        let mut all = vec!["cangate", "sdo"];
        all.extend_from_slice(argv);
        match Cli::try_parse_from(&all) {
            Ok(Cli {
                command: Command::Sdo(a),
                ..
            }) => a.verb,
            Ok(other) => panic!("{other:?}"),
            Err(e) => panic!("{all:?}: {e}"),
        }
    }

    /// The object, type and value of an `sdo write`.
    fn write(argv: &[&str]) -> (Object, Option<TypeArg>, Option<String>) {
        let SdoVerb::Write {
            object,
            words,
            file,
            ..
        } = sdo(argv)
        else {
            panic!()
        };
        let (ty, value) = type_and_value(&words, file.is_some()).unwrap();
        (object, ty, value)
    }

    #[test]
    fn options_may_follow_the_type_and_value() {
        let hoist = |argv: &[&str]| -> Vec<String> {
            hoist_write_options(argv.iter().map(Into::into).collect())
                .into_iter()
                .map(|a| a.into_string().unwrap())
                .collect()
        };
        // The README's order.
        let argv = hoist(&[
            "cangate", "sdo", "write", "can0", "1", "0x2100", "domain", "--file", "fw.bin",
            "--block",
        ]);
        let all: Vec<&str> = argv.iter().map(String::as_str).collect();
        let SdoVerb::Write {
            words,
            file,
            transfer,
            ..
        } = sdo(&all[2..])
        else {
            panic!()
        };
        assert_eq!(words, ["domain"]);
        assert_eq!(file, Some(PathBuf::from("fw.bin")));
        assert!(transfer.block);
        // Global options and inline values too; a value after `--` stays.
        let argv = hoist(&[
            "cangate",
            "sdo",
            "write",
            "can0",
            "1",
            "0x2000",
            "vs",
            "--json",
            "--sdo-timeout-ms=900",
            "--",
            "--block",
        ]);
        assert_eq!(
            argv[3..],
            [
                "--json",
                "--sdo-timeout-ms=900",
                "can0",
                "1",
                "0x2000",
                "vs",
                "--",
                "--block"
            ]
        );
        // Other commands are left alone.
        let argv = hoist(&["cangate", "sdo", "read", "can0", "1", "0x1008", "--block"]);
        assert_eq!(argv[2], "read");
        assert_eq!(argv[6], "--block");
    }

    #[test]
    fn negative_values_need_no_double_dash() {
        let (object, ty, value) = write(&["write", "can0", "1", "0x607A", "i32", "-5000"]);
        assert_eq!(object, Object::Address(ObjectAddress::new(0x607A, 0)));
        assert_eq!(ty, Some(TypeArg::I32));
        assert_eq!(
            parse_value(TypeArg::I32, value.as_deref().unwrap()).unwrap(),
            SdoValue::I32(-5000)
        );
        // A string starting with a dash is a value too, with a type or not.
        let (_, _, value) = write(&["write", "can0", "1", "0x2000", "vs", "-x-"]);
        assert_eq!(value.as_deref(), Some("-x-"));
        let (_, ty, value) = write(&["write", "can0", "1", "0x607A", "-5000"]);
        assert_eq!((ty, value.as_deref()), (None, Some("-5000")));
    }

    #[test]
    fn objects_by_name_and_writes_without_a_type() {
        let (object, ty, value) = write(&["write", "can0", "1", "Producer heartbeat time", "100"]);
        assert_eq!(object, Object::Name("Producer heartbeat time".into()));
        assert_eq!((ty, value.as_deref()), (None, Some("100")));
        let SdoVerb::Read { object, .. } = sdo(&["read", "can0", "1", "Identity object.Vendor-ID"])
        else {
            panic!()
        };
        assert_eq!(object, Object::Name("Identity object.Vendor-ID".into()));
        // Addresses stay addresses; a name of hex letters stays a name.
        for (text, want) in [
            ("0x1018:01", Object::Address(ObjectAddress::new(0x1018, 1))),
            ("1017", Object::Address(ObjectAddress::new(0x1017, 0))),
            ("Feed", Object::Name("Feed".into())),
        ] {
            assert_eq!(object_of(text), want, "{text}");
        }
        // A lone type name is a forgotten value; `vs u8` writes the text.
        let words = |w: &[&str]| w.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        assert!(
            type_and_value(&words(&["u8"]), false)
                .unwrap_err()
                .contains("vs u8")
        );
        assert!(type_and_value(&words(&["i7", "1"]), false).is_err());
        assert_eq!(
            type_and_value(&words(&["domain"]), true).unwrap(),
            (Some(TypeArg::Domain), None)
        );
        assert!(type_and_value(&words(&["u8", "1"]), true).is_err());
    }

    fn object_of(text: &str) -> Object {
        object(text).unwrap()
    }

    #[test]
    fn node_ids_and_objects_are_checked_by_clap() {
        let SdoVerb::Read { object, ty, .. } = sdo(&["read", "can0", "5", "0x1018:1", "-t", "u32"])
        else {
            panic!()
        };
        assert_eq!(
            (object, ty),
            (
                Object::Address(ObjectAddress::new(0x1018, 1)),
                Some(TypeArg::U32)
            )
        );
        for bad in [
            &["read", "can0", "0", "0x1000"][..],
            &["read", "can0", "128", "0x1000"],
            &["read", "can0", "1", "0x10000"],
            &["read", "can0", "1", "0x1000", "--type", "i7"],
            &["write", "can0", "1", "0x1000", "u8", "1", "2"],
        ] {
            let mut all = vec!["cangate", "sdo"];
            all.extend_from_slice(bad);
            assert!(Cli::try_parse_from(&all).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn values_parse_per_type() {
        assert_eq!(
            parse_value(TypeArg::U16, "0x10").unwrap(),
            SdoValue::U16(16)
        );
        assert_eq!(
            parse_value(TypeArg::I8, "-128").unwrap(),
            SdoValue::I8(-128)
        );
        assert!(
            parse_value(TypeArg::U8, "256")
                .unwrap_err()
                .contains("UNSIGNED8")
        );
        assert!(parse_value(TypeArg::U32, "-1").is_err());
        assert_eq!(
            parse_value(TypeArg::Bool, "on").unwrap(),
            SdoValue::Bool(true)
        );
        assert!(parse_value(TypeArg::Bool, "maybe").is_err());
        assert_eq!(
            parse_value(TypeArg::F32, "1.5").unwrap(),
            SdoValue::F32(1.5)
        );
        assert_eq!(
            parse_value(TypeArg::Os, "0102").unwrap(),
            SdoValue::OctetString(vec![1, 2])
        );
        assert_eq!(
            parse_value(TypeArg::U64, "18446744073709551615").unwrap(),
            SdoValue::U64(u64::MAX)
        );
    }
}
