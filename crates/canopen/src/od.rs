//! The object dictionary model (CiA 301 §7.4): objects by index, each
//! holding typed sub-objects ([`Variable`]s) with access rights, PDO
//! mappability, limits and default values.
//!
//! Usually built by [`crate::eds`] from an EDS/DCF file. Lookups take an
//! [`ObjectAddress`] ([`ObjectDictionary::get`]) or the text a person types
//! ([`ObjectDictionary::resolve`]): `0x1017`, `0x1018:01`,
//! `Producer heartbeat time`, `identity object.vendor-id`.

use std::collections::BTreeMap;
use std::fmt;
use std::str::FromStr;

use crate::ids::{Index, NodeId, ObjectAddress, SubIndex};
use crate::value::{DataType, Value, ValueError};

/// The object code of an object (CiA 301 table 42; EDS `ObjectType`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ObjectType {
    /// `NULL` (0x0): an object with no data.
    Null,
    /// `DOMAIN` (0x2): a large block of data, one sub-object.
    Domain,
    /// `DEFTYPE` (0x5): a type definition, one sub-object.
    DefType,
    /// `DEFSTRUCT` (0x6): a record type definition, with sub-objects.
    DefStruct,
    /// `VAR` (0x7): a single value at sub-index 0.
    Var,
    /// `ARRAY` (0x8): sub-objects of one type; sub 0 is the entry count.
    Array,
    /// `RECORD` (0x9): sub-objects of any types; sub 0 is the entry count.
    Record,
}

impl ObjectType {
    /// The CiA 301 object code.
    pub const fn code(self) -> u8 {
        match self {
            ObjectType::Null => 0x0,
            ObjectType::Domain => 0x2,
            ObjectType::DefType => 0x5,
            ObjectType::DefStruct => 0x6,
            ObjectType::Var => 0x7,
            ObjectType::Array => 0x8,
            ObjectType::Record => 0x9,
        }
    }

    /// The object type with this code.
    pub fn from_code(code: u8) -> Option<ObjectType> {
        use ObjectType as O;
        [
            O::Null,
            O::Domain,
            O::DefType,
            O::DefStruct,
            O::Var,
            O::Array,
            O::Record,
        ]
        .into_iter()
        .find(|o| o.code() == code)
    }

    /// True for the types made of several sub-objects (ARRAY, RECORD,
    /// DEFSTRUCT); the others hold one value at sub-index 0.
    pub const fn is_compound(self) -> bool {
        matches!(
            self,
            ObjectType::Array | ObjectType::Record | ObjectType::DefStruct
        )
    }
}

impl fmt::Display for ObjectType {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            ObjectType::Null => "NULL",
            ObjectType::Domain => "DOMAIN",
            ObjectType::DefType => "DEFTYPE",
            ObjectType::DefStruct => "DEFSTRUCT",
            ObjectType::Var => "VAR",
            ObjectType::Array => "ARRAY",
            ObjectType::Record => "RECORD",
        })
    }
}

/// Access rights of a sub-object (EDS `AccessType`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum AccessType {
    /// Read only.
    Ro,
    /// Write only.
    Wo,
    /// Read and write.
    Rw,
    /// Read and write; mappable into TPDOs (the device writes it).
    Rwr,
    /// Read and write; mappable into RPDOs (the bus writes it).
    Rww,
    /// Read only, never changes.
    Const,
}

impl AccessType {
    /// True unless write-only.
    pub const fn is_readable(self) -> bool {
        !matches!(self, AccessType::Wo)
    }

    /// True for `wo`, `rw`, `rwr` and `rww`.
    pub const fn is_writable(self) -> bool {
        matches!(
            self,
            AccessType::Wo | AccessType::Rw | AccessType::Rwr | AccessType::Rww
        )
    }

    /// The EDS spelling: `ro`, `wo`, `rw`, `rwr`, `rww` or `const`.
    pub const fn as_str(self) -> &'static str {
        match self {
            AccessType::Ro => "ro",
            AccessType::Wo => "wo",
            AccessType::Rw => "rw",
            AccessType::Rwr => "rwr",
            AccessType::Rww => "rww",
            AccessType::Const => "const",
        }
    }
}

impl fmt::Display for AccessType {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// An access type other than `ro`, `wo`, `rw`, `rwr`, `rww`, `const`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown access type {0:?} (expected ro, wo, rw, rwr, rww or const)")]
pub struct BadAccessType(pub String);

impl FromStr for AccessType {
    type Err = BadAccessType;

    /// Parses the EDS spelling, case-insensitively.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        use AccessType as A;
        [A::Ro, A::Wo, A::Rw, A::Rwr, A::Rww, A::Const]
            .into_iter()
            .find(|a| a.as_str().eq_ignore_ascii_case(s.trim()))
            .ok_or_else(|| BadAccessType(s.to_owned()))
    }
}

/// A default or configured value from an EDS/DCF, possibly written relative
/// to the node id (`$NODEID+0x180`).
#[derive(Debug, Clone, PartialEq)]
pub struct DefaultValue {
    /// The value; for a node-relative default, the part added to the node
    /// id (`0x180` for `$NODEID+0x180`).
    pub value: Value,
    /// True when the node id is added to `value`.
    pub node_relative: bool,
}

impl DefaultValue {
    /// A value that does not depend on the node id.
    pub fn fixed(value: Value) -> Self {
        DefaultValue {
            value,
            node_relative: false,
        }
    }

    /// The value for a node: `value + node` when node-relative (wrapping
    /// in the type's width; the EDS parser rejects defaults that could
    /// overflow), else `value`.
    pub fn resolve(&self, node: NodeId) -> Value {
        match (self.node_relative, self.value.as_i128()) {
            (true, Some(base)) => {
                Value::from_integer_wrapping(self.value.data_type(), base + i128::from(node.get()))
                    .unwrap_or_else(|| self.value.clone())
            }
            _ => self.value.clone(),
        }
    }

    /// Parses a CiA 306 `DefaultValue`/`ParameterValue` of type `ty`: a value
    /// in EDS syntax ([`Value::parse_eds`]), or for integer types a sum
    /// containing `$NODEID` once, e.g. `$NODEID+0x180`, `0x600 + $NODEID`.
    /// A node-relative value must fit the type for every node id 1..=127.
    pub fn parse(ty: DataType, text: &str) -> Result<DefaultValue, ValueError> {
        if !text.to_ascii_uppercase().contains("$NODEID") {
            return Value::parse_eds(ty, text).map(DefaultValue::fixed);
        }
        let invalid = |reason: &str| ValueError::Invalid {
            ty,
            text: text.to_owned(),
            reason: reason.into(),
        };
        if !ty.is_integer() {
            return Err(invalid("$NODEID is only allowed in integer values"));
        }
        // Split into signed terms: "$NODEID+0x180" -> [+$NODEID, +0x180].
        let compact: String = text.chars().filter(|c| !c.is_whitespace()).collect();
        let (mut base, mut nodes) = (0i128, 0);
        let mut rest = compact.as_str();
        while !rest.is_empty() {
            let negative = rest.starts_with('-');
            rest = rest.strip_prefix(['+', '-']).unwrap_or(rest);
            let end = rest.find(['+', '-']).unwrap_or(rest.len());
            let (term, tail) = rest.split_at(end);
            rest = tail;
            if term.eq_ignore_ascii_case("$NODEID") {
                if negative {
                    return Err(invalid("$NODEID may only be added"));
                }
                nodes += 1;
            } else {
                let v = Value::parse_eds(DataType::Unsigned64, term)
                    .ok()
                    .and_then(|v| v.as_i128())
                    .ok_or_else(|| invalid("expected numbers added to $NODEID"))?;
                base += if negative { -v } else { v };
            }
        }
        if nodes != 1 {
            return Err(invalid("$NODEID must appear exactly once"));
        }
        Value::from_integer(ty, base + 1)?;
        Value::from_integer(ty, base + 127)?;
        Ok(DefaultValue {
            value: Value::from_integer_wrapping(ty, base).unwrap_or(Value::zero(ty)),
            node_relative: true,
        })
    }
}

impl fmt::Display for DefaultValue {
    /// `$NODEID+0x180` for node-relative values, the value otherwise.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.node_relative {
            write!(f, "$NODEID+{:#X}", self.value.as_i128().unwrap_or_default())
        } else {
            write!(f, "{}", self.value)
        }
    }
}

/// One sub-object: a typed value slot at an [`ObjectAddress`].
#[derive(Debug, Clone, PartialEq)]
pub struct Variable {
    /// Where it lives.
    pub address: ObjectAddress,
    /// `ParameterName` (for a VAR, the object's name).
    pub name: String,
    /// Its type.
    pub data_type: DataType,
    /// Access rights.
    pub access: AccessType,
    /// Whether it may be mapped into a PDO.
    pub pdo_mappable: bool,
    /// `LowLimit`, if given.
    pub low_limit: Option<Value>,
    /// `HighLimit`, if given.
    pub high_limit: Option<Value>,
    /// `DefaultValue`, if given.
    pub default: Option<DefaultValue>,
    /// A DCF's configured `ParameterValue`, if given; takes precedence over
    /// `default` in [`Variable::default_for_node`].
    pub parameter_value: Option<DefaultValue>,
}

impl Variable {
    /// A variable without limits or defaults, not PDO-mappable.
    pub fn new(
        address: ObjectAddress,
        name: impl Into<String>,
        data_type: DataType,
        access: AccessType,
    ) -> Self {
        Variable {
            address,
            name: name.into(),
            data_type,
            access,
            pdo_mappable: false,
            low_limit: None,
            high_limit: None,
            default: None,
            parameter_value: None,
        }
    }

    /// The initial value on node `node`: the `ParameterValue` if any, else
    /// the `DefaultValue`, with `$NODEID` resolved.
    pub fn default_for_node(&self, node: NodeId) -> Option<Value> {
        self.parameter_value
            .as_ref()
            .or(self.default.as_ref())
            .map(|d| d.resolve(node))
    }

    /// Checks that `value` has this variable's type and lies within its
    /// limits (for SDO aborts 0x06070010, 0x06090031 and 0x06090032).
    pub fn check(&self, value: &Value) -> Result<(), ValueError> {
        if value.data_type() != self.data_type {
            return Err(ValueError::TypeMismatch {
                expected: self.data_type,
                got: value.data_type(),
            });
        }
        let below = |limit: &Value| compare(value, limit).is_some_and(|o| o.is_lt());
        let above = |limit: &Value| compare(value, limit).is_some_and(|o| o.is_gt());
        let err = |limit: &Value| (value.to_string(), limit.to_string());
        match (&self.low_limit, &self.high_limit) {
            (Some(low), _) if below(low) => {
                let (value, limit) = err(low);
                Err(ValueError::BelowLimit { value, limit })
            }
            (_, Some(high)) if above(high) => {
                let (value, limit) = err(high);
                Err(ValueError::AboveLimit { value, limit })
            }
            _ => Ok(()),
        }
    }

    /// The PDO mapping entry for this variable (`index << 16 | sub << 8 |
    /// bits`), or `None` if it is not mappable or has no fixed size.
    pub fn pdo_mapping_entry(&self) -> Option<u32> {
        let bits = self.data_type.bit_len().filter(|_| self.pdo_mappable)?;
        Some((u32::from(self.address.index) << 16) | (u32::from(self.address.sub) << 8) | bits)
    }
}

/// Orders two numbers (integers exactly, floats as `f64`).
fn compare(a: &Value, b: &Value) -> Option<std::cmp::Ordering> {
    match (a.as_i128(), b.as_i128()) {
        (Some(x), Some(y)) => Some(x.cmp(&y)),
        _ => a.as_f64()?.partial_cmp(&b.as_f64()?),
    }
}

/// One object at an index, with its sub-objects.
#[derive(Debug, Clone, PartialEq)]
pub struct Object {
    /// Its index.
    pub index: Index,
    /// `ParameterName`.
    pub name: String,
    /// Object code.
    pub object_type: ObjectType,
    /// Sub-objects by sub-index; a VAR, DOMAIN or DEFTYPE has exactly one,
    /// at sub-index 0.
    pub subs: BTreeMap<SubIndex, Variable>,
}

impl Object {
    /// An object without sub-objects.
    pub fn new(index: Index, name: impl Into<String>, object_type: ObjectType) -> Self {
        Object {
            index,
            name: name.into(),
            object_type,
            subs: BTreeMap::new(),
        }
    }

    /// A VAR object holding `variable` (whose address must be `index:00`).
    pub fn var(variable: Variable) -> Self {
        let mut object = Object::new(
            variable.address.index,
            variable.name.clone(),
            ObjectType::Var,
        );
        object.subs.insert(0, variable);
        object
    }

    /// The sub-object at `sub`.
    pub fn sub(&self, sub: SubIndex) -> Option<&Variable> {
        self.subs.get(&sub)
    }
}

/// A text lookup that did not name exactly one variable.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum LookupError {
    /// Nothing matches.
    #[error("no object {0:?} in the object dictionary")]
    NotFound(String),
    /// Several sub-objects carry that name.
    #[error("{query:?} is ambiguous: it names {} (qualify it as \"object.sub\")", list(.matches))]
    Ambiguous {
        /// The text looked up.
        query: String,
        /// The candidates.
        matches: Vec<ObjectAddress>,
    },
}

fn list(addresses: &[ObjectAddress]) -> String {
    addresses
        .iter()
        .map(ToString::to_string)
        .collect::<Vec<_>>()
        .join(", ")
}

/// Lower-cases and treats `_`, `-` and runs of spaces alike, so
/// `vendor_id` finds `Vendor-ID`.
fn normalize(name: &str) -> String {
    let spaced: String = name
        .chars()
        .map(|c| {
            if matches!(c, '_' | '-') {
                ' '
            } else {
                c.to_ascii_lowercase()
            }
        })
        .collect();
    spaced.split_whitespace().collect::<Vec<_>>().join(" ")
}

/// Parses a hex number with optional `0x`, of at most `max_digits` digits.
fn parse_hex(text: &str, max_digits: usize) -> Option<u32> {
    let t = text.trim();
    let (digits, prefixed) = match t.strip_prefix("0x").or_else(|| t.strip_prefix("0X")) {
        Some(d) => (d, true),
        None => (t, false),
    };
    let ok_len = if prefixed {
        (1..=max_digits).contains(&digits.len())
    } else {
        digits.len() == max_digits || max_digits == 2 && digits.len() == 1
    };
    (ok_len && digits.chars().all(|c| c.is_ascii_hexdigit()))
        .then(|| u32::from_str_radix(digits, 16).ok())
        .flatten()
}

/// An object dictionary: objects ordered by index.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ObjectDictionary {
    objects: BTreeMap<Index, Object>,
}

impl ObjectDictionary {
    /// An empty dictionary.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds or replaces an object; returns the one replaced.
    pub fn insert(&mut self, object: Object) -> Option<Object> {
        self.objects.insert(object.index, object)
    }

    /// The object at `index`.
    pub fn object(&self, index: Index) -> Option<&Object> {
        self.objects.get(&index)
    }

    /// The object at `index`, mutably.
    pub fn object_mut(&mut self, index: Index) -> Option<&mut Object> {
        self.objects.get_mut(&index)
    }

    /// The variable at `address`.
    pub fn get(&self, address: ObjectAddress) -> Option<&Variable> {
        self.objects.get(&address.index)?.subs.get(&address.sub)
    }

    /// The variable at `address`, mutably.
    pub fn get_mut(&mut self, address: ObjectAddress) -> Option<&mut Variable> {
        self.objects
            .get_mut(&address.index)?
            .subs
            .get_mut(&address.sub)
    }

    /// Number of objects.
    pub fn len(&self) -> usize {
        self.objects.len()
    }

    /// True when there are no objects.
    pub fn is_empty(&self) -> bool {
        self.objects.is_empty()
    }

    /// Objects in index order.
    pub fn objects(&self) -> impl Iterator<Item = &Object> {
        self.objects.values()
    }

    /// Every variable, in address order.
    pub fn variables(&self) -> impl Iterator<Item = &Variable> {
        self.objects.values().flat_map(|o| o.subs.values())
    }

    /// The initial value of every variable that has one on node `node`
    /// (see [`Variable::default_for_node`]), in address order.
    pub fn defaults_for_node(
        &self,
        node: NodeId,
    ) -> impl Iterator<Item = (ObjectAddress, Value)> + '_ {
        self.variables()
            .filter_map(move |v| Some((v.address, v.default_for_node(node)?)))
    }

    /// The name a person gives the variable at `address`, which
    /// [`ObjectDictionary::resolve`] takes back: the object's name for a
    /// single-value object (VAR, DOMAIN, DEFTYPE: `Producer heartbeat
    /// time`), `object.sub` for a sub-object of an ARRAY, RECORD or
    /// DEFSTRUCT (`Identity object.Vendor-ID`).
    pub fn full_name(&self, address: ObjectAddress) -> Option<String> {
        let object = self.object(address.index)?;
        let variable = object.sub(address.sub)?;
        Some(if object.object_type.is_compound() {
            format!("{}.{}", object.name, variable.name)
        } else {
            object.name.clone()
        })
    }

    /// The variable named by `query` (see [`ObjectDictionary::resolve`]).
    pub fn find(&self, query: &str) -> Option<&Variable> {
        self.resolve(query).ok().and_then(|a| self.get(a))
    }

    /// Resolves what a person typed to the address of an existing variable.
    ///
    /// * an object: `0x1017`, `1017` (4 hex digits) or its name
    ///   (`Producer heartbeat time`) means sub-index 0;
    /// * `object:sub` or `object.sub`, where sub is a hex sub-index (`1`,
    ///   `0A`, `0x0A`, as [`ObjectAddress`] displays it) or a sub-object
    ///   name: `0x1018:01`, `Identity object.Vendor-ID`;
    /// * a sub-object name alone (`Vendor-ID`) if only one object has it.
    ///
    /// Names match case-insensitively, with `_`, `-` and spaces alike.
    pub fn resolve(&self, query: &str) -> Result<ObjectAddress, LookupError> {
        let not_found = || LookupError::NotFound(query.to_owned());
        let q = query.trim();
        if let Some(index) = self.object_index(q) {
            let address = ObjectAddress::new(index?, 0);
            return self.get(address).map(|_| address).ok_or_else(not_found);
        }
        let wanted = normalize(q);
        let matches: Vec<ObjectAddress> = self
            .variables()
            .filter(|v| normalize(&v.name) == wanted)
            .map(|v| v.address)
            .collect();
        match matches.len() {
            0 => {}
            1 => return Ok(matches[0]),
            _ => {
                return Err(LookupError::Ambiguous {
                    query: query.to_owned(),
                    matches,
                });
            }
        }
        for (pos, _) in q
            .match_indices([':', '.'])
            .collect::<Vec<_>>()
            .into_iter()
            .rev()
        {
            let Some(index) = self.object_index(&q[..pos]) else {
                continue;
            };
            let object = self.object(index?).ok_or_else(not_found)?;
            let sub_text = &q[pos + 1..];
            let sub = object
                .subs
                .values()
                .find(|v| normalize(&v.name) == normalize(sub_text))
                .map(|v| v.address.sub)
                .or_else(|| parse_hex(sub_text, 2).and_then(|s| u8::try_from(s).ok()))
                .filter(|s| object.subs.contains_key(s));
            return sub
                .map(|s| ObjectAddress::new(object.index, s))
                .ok_or_else(not_found);
        }
        Err(not_found())
    }

    /// `Some(Ok(index))` when `text` is an index or names one object;
    /// `None` when it names none.
    /// Names win over bare hex (an object may be called "Feed"); `0x`
    /// indices are taken even if absent, bare ones only if present.
    fn object_index(&self, text: &str) -> Option<Result<Index, LookupError>> {
        let wanted = normalize(text);
        let matches: Vec<&Object> = self
            .objects()
            .filter(|o| normalize(&o.name) == wanted)
            .collect();
        match matches.as_slice() {
            [] => {
                let index = parse_hex(text, 4)? as Index;
                let prefixed = text.trim().to_ascii_lowercase().starts_with("0x");
                (prefixed || self.objects.contains_key(&index)).then_some(Ok(index))
            }
            [one] => Some(Ok(one.index)),
            many => Some(Err(LookupError::Ambiguous {
                query: text.to_owned(),
                matches: many
                    .iter()
                    .map(|o| ObjectAddress::new(o.index, 0))
                    .collect(),
            })),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn node(n: u32) -> NodeId {
        NodeId::new(n).unwrap()
    }

    fn sample() -> ObjectDictionary {
        let mut od = ObjectDictionary::new();
        let mut hb = Variable::new(
            ObjectAddress::new(0x1017, 0),
            "Producer heartbeat time",
            DataType::Unsigned16,
            AccessType::Rw,
        );
        hb.default = Some(DefaultValue::fixed(Value::Unsigned16(1000)));
        hb.low_limit = Some(Value::Unsigned16(10));
        hb.high_limit = Some(Value::Unsigned16(60000));
        od.insert(Object::var(hb));
        let mut identity = Object::new(0x1018, "Identity object", ObjectType::Record);
        for (sub, name, ty) in [
            (0, "Highest sub-index supported", DataType::Unsigned8),
            (1, "Vendor-ID", DataType::Unsigned32),
            (2, "Product code", DataType::Unsigned32),
        ] {
            identity.subs.insert(
                sub,
                Variable::new(ObjectAddress::new(0x1018, sub), name, ty, AccessType::Ro),
            );
        }
        od.insert(identity);
        let mut sdo = Object::new(0x1200, "SDO server parameter", ObjectType::Record);
        sdo.subs.insert(
            0,
            Variable::new(
                ObjectAddress::new(0x1200, 0),
                "Highest sub-index supported",
                DataType::Unsigned8,
                AccessType::Const,
            ),
        );
        let mut cob = Variable::new(
            ObjectAddress::new(0x1200, 1),
            "COB-ID client to server",
            DataType::Unsigned32,
            AccessType::Ro,
        );
        cob.default = Some(DefaultValue::parse(DataType::Unsigned32, "$NODEID+0x600").unwrap());
        sdo.subs.insert(1, cob);
        od.insert(sdo);
        od
    }

    #[test]
    fn codes_and_access() {
        for code in 0..=10 {
            if let Some(o) = ObjectType::from_code(code) {
                assert_eq!(o.code(), code);
            }
        }
        assert_eq!(ObjectType::from_code(0x9), Some(ObjectType::Record));
        assert_eq!(ObjectType::from_code(0x3), None);
        assert_eq!("RWW".parse::<AccessType>().unwrap(), AccessType::Rww);
        assert!(AccessType::Const.is_readable() && !AccessType::Const.is_writable());
        assert!(!AccessType::Wo.is_readable() && AccessType::Wo.is_writable());
        assert_eq!(
            "rx".parse::<AccessType>().unwrap_err().to_string(),
            "unknown access type \"rx\" (expected ro, wo, rw, rwr, rww or const)"
        );
    }

    #[test]
    fn lookup_by_address_and_text() {
        let od = sample();
        let hb = ObjectAddress::new(0x1017, 0);
        assert_eq!(od.get(hb).unwrap().name, "Producer heartbeat time");
        assert!(od.get(ObjectAddress::new(0x1017, 1)).is_none());
        for q in [
            "0x1017",
            "1017",
            "producer heartbeat time",
            " Producer_Heartbeat_Time ",
            "0x1017:0",
        ] {
            assert_eq!(od.resolve(q), Ok(hb), "{q}");
        }
        let vendor = ObjectAddress::new(0x1018, 1);
        for q in [
            "0x1018:01",
            "0x1018:1",
            "1018.1",
            "0x1018:0x01",
            "Identity object.Vendor-ID",
            "identity_object:vendor id",
            "vendor-id",
            "0x1018:vendor_id",
        ] {
            assert_eq!(od.resolve(q), Ok(vendor), "{q}");
        }
        assert_eq!(od.resolve("0x1018"), Ok(ObjectAddress::new(0x1018, 0)));
        assert_eq!(
            od.find("product code").unwrap().address,
            ObjectAddress::new(0x1018, 2)
        );
        assert_eq!(
            od.resolve("0x2000"),
            Err(LookupError::NotFound("0x2000".into()))
        );
        assert_eq!(
            od.resolve("0x1018:09"),
            Err(LookupError::NotFound("0x1018:09".into()))
        );
        assert!(od.resolve("nope").is_err());
        let err = od.resolve("Highest sub-index supported").unwrap_err();
        assert_eq!(
            err.to_string(),
            "\"Highest sub-index supported\" is ambiguous: it names 0x1018:00, 0x1200:00 (qualify it as \"object.sub\")"
        );
        assert_eq!(
            od.resolve("SDO server parameter.highest sub-index supported"),
            Ok(ObjectAddress::new(0x1200, 0))
        );
    }

    #[test]
    fn full_names_resolve_back() {
        let od = sample();
        assert_eq!(
            od.full_name(ObjectAddress::new(0x1018, 1)).as_deref(),
            Some("Identity object.Vendor-ID")
        );
        assert_eq!(
            od.full_name(ObjectAddress::new(0x1017, 0)).as_deref(),
            Some("Producer heartbeat time")
        );
        assert_eq!(od.full_name(ObjectAddress::new(0x1017, 1)), None);
        // Every name of the built-in device descriptions finds its object.
        for text in [
            crate::eds::SIM_DRIVE_EDS,
            crate::eds::SIM_IO_EDS,
            crate::eds::SIM_HANDWHEEL_EDS,
        ] {
            let od = crate::eds::Eds::parse(text).unwrap().od;
            for v in od.variables() {
                let name = od.full_name(v.address).unwrap();
                assert_eq!(od.resolve(&name), Ok(v.address), "{name}");
            }
        }
    }

    #[test]
    fn node_relative_defaults() {
        let od = sample();
        let cob = od.get(ObjectAddress::new(0x1200, 1)).unwrap();
        assert_eq!(cob.default.as_ref().unwrap().to_string(), "$NODEID+0x600");
        assert_eq!(
            cob.default_for_node(node(5)),
            Some(Value::Unsigned32(0x605))
        );
        let defaults: Vec<_> = od.defaults_for_node(node(0x7F)).collect();
        assert_eq!(
            defaults,
            [
                (ObjectAddress::new(0x1017, 0), Value::Unsigned16(1000)),
                (ObjectAddress::new(0x1200, 1), Value::Unsigned32(0x67F))
            ]
        );
        let d = |text| DefaultValue::parse(DataType::Unsigned32, text);
        assert_eq!(
            d("0x80000000 + $nodeid + 0x180").unwrap().resolve(node(1)),
            Value::Unsigned32(0x8000_0181)
        );
        assert_eq!(d("$NODEID").unwrap().resolve(node(3)), Value::Unsigned32(3));
        assert!(d("$NODEID+$NODEID").is_err());
        assert!(d("0x200-$NODEID").is_err());
        assert!(d("$NODEID*2").is_err());
        assert!(DefaultValue::parse(DataType::Real32, "$NODEID").is_err());
        // Must fit for every node id.
        let err = DefaultValue::parse(DataType::Unsigned8, "$NODEID+200").unwrap_err();
        assert_eq!(
            err.to_string(),
            "value 327 does not fit UNSIGNED8 (0..=255)"
        );
        // ParameterValue takes precedence.
        let mut v = cob.clone();
        v.parameter_value = Some(DefaultValue::fixed(Value::Unsigned32(0x8000_0000)));
        assert_eq!(
            v.default_for_node(node(5)),
            Some(Value::Unsigned32(0x8000_0000))
        );
    }

    #[test]
    fn limits_and_mapping() {
        let od = sample();
        let hb = od.get(ObjectAddress::new(0x1017, 0)).unwrap();
        assert_eq!(hb.check(&Value::Unsigned16(100)), Ok(()));
        assert_eq!(
            hb.check(&Value::Unsigned16(5)).unwrap_err().to_string(),
            "value 5 is below the low limit 10"
        );
        assert!(matches!(
            hb.check(&Value::Unsigned16(65000)),
            Err(ValueError::AboveLimit { .. })
        ));
        assert!(matches!(
            hb.check(&Value::Unsigned32(100)),
            Err(ValueError::TypeMismatch { .. })
        ));
        assert_eq!(hb.pdo_mapping_entry(), None);
        let mut mapped = hb.clone();
        mapped.pdo_mappable = true;
        assert_eq!(mapped.pdo_mapping_entry(), Some(0x1017_0010));
    }
}
