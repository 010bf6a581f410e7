//! The object dictionary: what a node's entries are (type, access, PDO mapping, default,
//! limits), read from an EDS file (CiA 306, the INI format every CANopen tool reads).
//!
//! The dictionary is a description; a device keeps its values elsewhere and uses
//! [`Variable::check_write`] to refuse bad writes with the abort code a real node gives.
//! EDS errors name the file, the line and `[section] key`, like every other data file
//! of the project.

use super::sdo::AbortCode;
use super::NodeId;
use crate::config::{ConfigError, Location};
use std::collections::BTreeMap;
use std::path::Path;

/// CiA 301 basic data types.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DataType {
    Boolean,
    Integer8,
    Integer16,
    Integer32,
    Integer64,
    Unsigned8,
    Unsigned16,
    Unsigned32,
    Unsigned64,
    Real32,
    Real64,
    VisibleString,
    OctetString,
    Domain,
}

impl DataType {
    pub fn from_code(code: u16) -> Option<Self> {
        Some(match code {
            0x01 => Self::Boolean,
            0x02 => Self::Integer8,
            0x03 => Self::Integer16,
            0x04 => Self::Integer32,
            0x05 => Self::Unsigned8,
            0x06 => Self::Unsigned16,
            0x07 => Self::Unsigned32,
            0x08 => Self::Real32,
            0x09 => Self::VisibleString,
            0x0A => Self::OctetString,
            0x0F => Self::Domain,
            0x11 => Self::Real64,
            0x15 => Self::Integer64,
            0x1B => Self::Unsigned64,
            _ => return None,
        })
    }

    /// Size in bytes of fixed-size types.
    pub fn size(self) -> Option<usize> {
        Some(match self {
            Self::Boolean | Self::Integer8 | Self::Unsigned8 => 1,
            Self::Integer16 | Self::Unsigned16 => 2,
            Self::Integer32 | Self::Unsigned32 | Self::Real32 => 4,
            Self::Integer64 | Self::Unsigned64 | Self::Real64 => 8,
            Self::VisibleString | Self::OctetString | Self::Domain => return None,
        })
    }

    pub fn is_signed(self) -> bool {
        matches!(
            self,
            Self::Integer8 | Self::Integer16 | Self::Integer32 | Self::Integer64
        )
    }

    pub fn is_integer(self) -> bool {
        !matches!(
            self,
            Self::Real32 | Self::Real64 | Self::VisibleString | Self::OctetString | Self::Domain
        )
    }
}

/// Access types of CiA 306.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Access {
    Ro,
    Wo,
    Rw,
    /// Read-write, mapped in a TPDO.
    Rwr,
    /// Read-write, mapped in an RPDO.
    Rww,
    Const,
}

impl Access {
    fn parse(s: &str) -> Option<Self> {
        Some(match s.to_ascii_lowercase().as_str() {
            "ro" => Self::Ro,
            "wo" => Self::Wo,
            "rw" => Self::Rw,
            "rwr" => Self::Rwr,
            "rww" => Self::Rww,
            "const" => Self::Const,
            _ => return None,
        })
    }

    pub fn readable(self) -> bool {
        self != Self::Wo
    }

    pub fn writable(self) -> bool {
        matches!(self, Self::Wo | Self::Rw | Self::Rwr | Self::Rww)
    }
}

/// One entry (index, subindex).
#[derive(Clone, Debug, PartialEq)]
pub struct Variable {
    pub index: u16,
    pub sub: u8,
    pub name: String,
    pub data_type: DataType,
    pub access: Access,
    pub pdo_mappable: bool,
    /// Default value as stored (little-endian bytes).
    pub default: Vec<u8>,
    pub low: Option<i64>,
    pub high: Option<i64>,
}

impl Variable {
    /// Refuse a write the way a node does: access, length, then value limits.
    pub fn check_write(&self, data: &[u8]) -> Result<(), AbortCode> {
        if !self.access.writable() {
            return Err(AbortCode::READ_ONLY);
        }
        if let Some(n) = self.data_type.size() {
            if data.len() > n {
                return Err(AbortCode::TOO_LONG);
            }
            if data.len() < n {
                return Err(AbortCode::TOO_SHORT);
            }
        }
        if self.data_type.is_integer() {
            let v = decode_int(self.data_type, data).ok_or(AbortCode::LENGTH_MISMATCH)?;
            if self.high.is_some_and(|h| v > h) {
                return Err(AbortCode::VALUE_TOO_HIGH);
            }
            if self.low.is_some_and(|l| v < l) {
                return Err(AbortCode::VALUE_TOO_LOW);
            }
        }
        Ok(())
    }

    pub fn check_read(&self) -> Result<(), AbortCode> {
        if self.access.readable() {
            Ok(())
        } else {
            Err(AbortCode::WRITE_ONLY)
        }
    }

    /// Mapping length in bits (for PDO mapping checks).
    pub fn bits(&self) -> Option<u8> {
        self.data_type.size().map(|n| (n * 8) as u8)
    }
}

/// An integer of a type as little-endian bytes (two's complement, truncated).
pub fn encode_int(t: DataType, v: i64) -> Vec<u8> {
    let n = t.size().unwrap_or(4);
    v.to_le_bytes()[..n].to_vec()
}

/// Little-endian bytes of an integer type as i64 (sign-extended for signed types).
pub fn decode_int(t: DataType, d: &[u8]) -> Option<i64> {
    let n = t.size()?;
    if d.len() != n || !t.is_integer() {
        return None;
    }
    let mut b = [0u8; 8];
    b[..n].copy_from_slice(d);
    let u = u64::from_le_bytes(b);
    Some(if t.is_signed() && n < 8 {
        let shift = 64 - 8 * n as u32;
        ((u << shift) as i64) >> shift
    } else {
        u as i64
    })
}

/// An object: a VAR (sub 0 only), an ARRAY or a RECORD.
#[derive(Clone, Debug, PartialEq)]
pub struct Object {
    pub index: u16,
    pub name: String,
    /// 0x7 VAR, 0x8 ARRAY, 0x9 RECORD (CiA 306).
    pub object_type: u8,
    pub subs: BTreeMap<u8, Variable>,
}

/// A node's object dictionary.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ObjectDictionary {
    /// Where it came from (for messages).
    pub source: String,
    pub objects: BTreeMap<u16, Object>,
    /// `[DeviceInfo]` keys as written (lower-cased names).
    pub device_info: BTreeMap<String, String>,
}

impl ObjectDictionary {
    /// The entry at `index:sub`, or the abort code a node answers for it.
    pub fn variable(&self, index: u16, sub: u8) -> Result<&Variable, AbortCode> {
        let o = self.objects.get(&index).ok_or(AbortCode::NO_OBJECT)?;
        o.subs.get(&sub).ok_or(AbortCode::NO_SUBINDEX)
    }

    pub fn variables(&self) -> impl Iterator<Item = &Variable> {
        self.objects.values().flat_map(|o| o.subs.values())
    }

    /// Read an EDS file for a node (its `$NODEID` references resolved to `node`).
    pub fn load_eds(path: &Path, node: NodeId) -> Result<Self, ConfigError> {
        let text = crate::config::read_data_file(path).map_err(|cause| ConfigError::Io {
            file: path.to_path_buf(),
            cause,
        })?;
        Self::from_eds(&path.display().to_string(), &text, node)
    }

    /// Parse EDS text; `name` is used in error messages.
    pub fn from_eds(name: &str, text: &str, node: NodeId) -> Result<Self, ConfigError> {
        let ini = Ini::parse(name, text)?;
        let mut od = ObjectDictionary {
            source: name.to_string(),
            ..Default::default()
        };
        if let Some(s) = ini.section("DeviceInfo") {
            for (k, (v, _)) in &s.keys {
                od.device_info.insert(k.clone(), v.clone());
            }
        }
        for s in &ini.sections {
            if let Some(index) = parse_index_section(&s.name) {
                let object_type = match s.get("objecttype") {
                    Some((v, line)) => parse_int(v)
                        .filter(|t| [0x7, 0x8, 0x9].contains(t))
                        .ok_or_else(|| {
                            ini.error(
                                Some(line),
                                &s.name,
                                "ObjectType",
                                format!("`{v}`: expected 0x7 (VAR), 0x8 (ARRAY) or 0x9 (RECORD)"),
                            )
                        })? as u8,
                    None => 0x7,
                };
                if s.get("compactsubobj").is_some() {
                    return Err(ini.error(s.line.into(), &s.name, "CompactSubObj", "compact sub-objects are not supported: write each sub-index as its own section"));
                }
                let name = s.require(&ini, "parametername")?.0.clone();
                let mut obj = Object {
                    index,
                    name,
                    object_type,
                    subs: BTreeMap::new(),
                };
                if object_type == 0x7 {
                    obj.subs.insert(0, build_variable(&ini, s, index, 0, node)?);
                }
                if od.objects.insert(index, obj).is_some() {
                    return Err(ini.error(Some(s.line), &s.name, "", "object defined twice"));
                }
            }
        }
        for s in &ini.sections {
            if let Some((index, sub)) = parse_sub_section(&s.name) {
                let v = build_variable(&ini, s, index, sub, node)?;
                let Some(obj) = od.objects.get_mut(&index) else {
                    return Err(ini.error(
                        Some(s.line),
                        &s.name,
                        "",
                        format!(
                            "sub-index of object 0x{index:04X}, which has no [{index:04X}] section"
                        ),
                    ));
                };
                if obj.object_type == 0x7 {
                    return Err(ini.error(
                        Some(s.line),
                        &s.name,
                        "",
                        format!("object 0x{index:04X} is a VAR and has no sub-indices"),
                    ));
                }
                obj.subs.insert(sub, v);
            }
        }
        if !od.objects.contains_key(&0x1000) {
            return Err(ini.error(
                None,
                "1000",
                "",
                "the mandatory object 0x1000 (device type) is missing",
            ));
        }
        Ok(od)
    }
}

fn parse_index_section(name: &str) -> Option<u16> {
    (name.len() == 4)
        .then(|| u16::from_str_radix(name, 16).ok())
        .flatten()
}

fn parse_sub_section(name: &str) -> Option<(u16, u8)> {
    if name.len() < 8
        || !name.is_char_boundary(4)
        || !name[4..].to_ascii_lowercase().starts_with("sub")
    {
        return None;
    }
    let index = u16::from_str_radix(&name[..4], 16).ok()?;
    let sub = u8::from_str_radix(&name[7..], 16).ok()?;
    Some((index, sub))
}

/// An EDS integer: decimal, `0x` hex, or octal with a leading 0 (as C's strtol).
fn parse_int(s: &str) -> Option<i64> {
    let s = s.trim();
    let (neg, s) = match s.strip_prefix('-') {
        Some(r) => (true, r),
        None => (false, s),
    };
    let v = if let Some(h) = s.strip_prefix("0x").or_else(|| s.strip_prefix("0X")) {
        i128::from_str_radix(h, 16).ok()?
    } else if s.len() > 1 && s.starts_with('0') {
        i128::from_str_radix(&s[1..], 8).ok()?
    } else {
        s.parse::<i128>().ok()?
    };
    let v = if neg { -v } else { v };
    // Hex of a signed type may be written as its unsigned pattern (0xFFFFFFFF).
    (v >= i128::from(i64::MIN) && v <= i128::from(u64::MAX)).then_some(v as i64)
}

/// `$NODEID+0x180`, `0x180+$NODEID`, or a plain integer.
fn parse_value_int(s: &str, node: NodeId) -> Option<i64> {
    let t: String = s
        .chars()
        .filter(|c| !c.is_whitespace())
        .collect::<String>()
        .to_ascii_uppercase();
    if t.contains("$NODEID") {
        let rest = t
            .replace("+$NODEID", "")
            .replace("$NODEID+", "")
            .replace("$NODEID", "");
        let base = if rest.is_empty() {
            0
        } else {
            parse_int(&rest.to_ascii_lowercase())?
        };
        return Some(base + i64::from(node.get()));
    }
    parse_int(&t.to_ascii_lowercase())
}

fn build_variable(
    ini: &Ini,
    s: &Section,
    index: u16,
    sub: u8,
    node: NodeId,
) -> Result<Variable, ConfigError> {
    let name = s.require(ini, "parametername")?.0.clone();
    let (dt_text, dt_line) = s.require(ini, "datatype")?;
    let data_type = parse_int(dt_text)
        .and_then(|c| u16::try_from(c).ok())
        .and_then(DataType::from_code)
        .ok_or_else(|| {
            ini.error(
                Some(*dt_line),
                &s.name,
                "DataType",
                format!("`{dt_text}` is not a supported CiA 301 basic data type"),
            )
        })?;
    let (acc_text, acc_line) = s.require(ini, "accesstype")?;
    let access = Access::parse(acc_text).ok_or_else(|| {
        ini.error(
            Some(*acc_line),
            &s.name,
            "AccessType",
            format!("`{acc_text}`: expected ro, wo, rw, rwr, rww or const"),
        )
    })?;
    let pdo_mappable = match s.get("pdomapping") {
        Some((v, line)) => match parse_int(v) {
            Some(0) => false,
            Some(1) => true,
            _ => {
                return Err(ini.error(
                    Some(line),
                    &s.name,
                    "PDOMapping",
                    format!("`{v}`: expected 0 or 1"),
                ))
            }
        },
        None => false,
    };
    let limit = |key: &str, label: &str| -> Result<Option<i64>, ConfigError> {
        match s.get(key) {
            Some((v, line)) if data_type.is_integer() => parse_int(v)
                .map(|x| Some(sign_extend(data_type, x)))
                .ok_or_else(|| {
                    ini.error(
                        Some(line),
                        &s.name,
                        label,
                        format!("`{v}` is not an integer"),
                    )
                }),
            _ => Ok(None),
        }
    };
    let low = limit("lowlimit", "LowLimit")?;
    let high = limit("highlimit", "HighLimit")?;
    let default = match s.get("defaultvalue") {
        None => default_of(data_type),
        Some((v, line)) => encode_default(data_type, v, node).ok_or_else(|| {
            ini.error(
                Some(line),
                &s.name,
                "DefaultValue",
                format!("`{v}` is not a valid {data_type:?} value"),
            )
        })?,
    };
    Ok(Variable {
        index,
        sub,
        name,
        data_type,
        access,
        pdo_mappable,
        default,
        low,
        high,
    })
}

fn sign_extend(t: DataType, v: i64) -> i64 {
    decode_int(t, &encode_int(t, v)).unwrap_or(v)
}

fn default_of(t: DataType) -> Vec<u8> {
    vec![0; t.size().unwrap_or(0)]
}

fn encode_default(t: DataType, v: &str, node: NodeId) -> Option<Vec<u8>> {
    match t {
        DataType::VisibleString => Some(v.as_bytes().to_vec()),
        DataType::OctetString | DataType::Domain => {
            let h: String = v.chars().filter(|c| !c.is_whitespace()).collect();
            // Hex digits only: slicing two bytes at a time is then always on a character
            // boundary (an EDS file may hold any bytes).
            if !h.len().is_multiple_of(2) || !h.bytes().all(|b| b.is_ascii_hexdigit()) {
                return None;
            }
            (0..h.len())
                .step_by(2)
                .map(|i| u8::from_str_radix(&h[i..i + 2], 16).ok())
                .collect()
        }
        DataType::Real32 => v
            .trim()
            .parse::<f32>()
            .ok()
            .map(|f| f.to_le_bytes().to_vec()),
        DataType::Real64 => v
            .trim()
            .parse::<f64>()
            .ok()
            .map(|f| f.to_le_bytes().to_vec()),
        _ if v.trim().is_empty() => Some(default_of(t)),
        _ => {
            let x = parse_value_int(v, node)?;
            let n = t.size()?;
            // The value must fit the type, as signed or as its unsigned pattern.
            let bits = 8 * n as u32;
            let fits = if bits == 64 {
                true
            } else if t.is_signed() {
                x >= -(1i64 << (bits - 1)) && x < (1i64 << bits)
            } else {
                x >= 0 && x < (1i64 << bits)
            };
            fits.then(|| encode_int(t, x))
        }
    }
}

// ------------------------------------------------------------------------- INI reader

struct Section {
    name: String,
    line: usize,
    /// Lower-cased key -> (value, line).
    keys: BTreeMap<String, (String, usize)>,
}

impl Section {
    fn get(&self, key: &str) -> Option<(&String, usize)> {
        self.keys.get(key).map(|(v, l)| (v, *l))
    }

    fn require<'a>(&'a self, ini: &Ini, key: &str) -> Result<(&'a String, &'a usize), ConfigError> {
        self.keys.get(key).map(|(v, l)| (v, l)).ok_or_else(|| {
            let label = match key {
                "parametername" => "ParameterName",
                "datatype" => "DataType",
                "accesstype" => "AccessType",
                other => other,
            };
            ini.error(Some(self.line), &self.name, label, "missing")
        })
    }
}

struct Ini {
    file: String,
    sections: Vec<Section>,
}

impl Ini {
    fn parse(file: &str, text: &str) -> Result<Self, ConfigError> {
        let mut ini = Ini {
            file: file.to_string(),
            sections: Vec::new(),
        };
        for (n, raw) in text.lines().enumerate() {
            let line = n + 1;
            let l = raw.trim();
            if l.is_empty() || l.starts_with(';') || l.starts_with('#') {
                continue;
            }
            if let Some(rest) = l.strip_prefix('[') {
                let Some(name) = rest.strip_suffix(']') else {
                    return Err(ini.error(Some(line), rest, "", "section header without `]`"));
                };
                let name = name.trim().to_string();
                if ini.sections.iter().any(|s| s.name == name) {
                    return Err(ini.error(Some(line), &name, "", "section appears twice"));
                }
                ini.sections.push(Section {
                    name,
                    line,
                    keys: BTreeMap::new(),
                });
                continue;
            }
            let Some((k, v)) = l.split_once('=') else {
                return Err(ini.error(
                    Some(line),
                    ini.sections.last().map_or("", |s| &s.name),
                    "",
                    format!("`{l}` is neither a [section] nor key=value"),
                ));
            };
            let Some(s) = ini.sections.last_mut() else {
                return Err(ini.error(Some(line), "", k.trim(), "key before any [section]"));
            };
            let key = k.trim().to_ascii_lowercase();
            if s.keys.insert(key, (v.trim().to_string(), line)).is_some() {
                let name = s.name.clone();
                return Err(ini.error(
                    Some(line),
                    &name,
                    k.trim(),
                    "key appears twice in the section",
                ));
            }
        }
        Ok(ini)
    }

    fn section(&self, name: &str) -> Option<&Section> {
        self.sections
            .iter()
            .find(|s| s.name.eq_ignore_ascii_case(name))
    }

    fn error(
        &self,
        line: Option<usize>,
        section: &str,
        key: &str,
        message: impl Into<String>,
    ) -> ConfigError {
        let key = if key.is_empty() {
            format!("[{section}]")
        } else {
            format!("[{section}] {key}")
        };
        ConfigError::Invalid {
            location: Location {
                file: self.file.clone(),
                line,
                column: None,
                key: Some(key),
            },
            message: message.into(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const EDS: &str = "\
[DeviceInfo]
VendorName=Test
ProductName=Drive

[1000]
ParameterName=Device type
ObjectType=0x7
DataType=0x0007
AccessType=ro
DefaultValue=0x00020192
PDOMapping=0

[1400]
ParameterName=RPDO1 communication parameter
ObjectType=0x9
SubNumber=2

[1400sub0]
ParameterName=Highest sub-index supported
DataType=0x0005
AccessType=const
DefaultValue=2

[1400sub1]
ParameterName=COB-ID used by RPDO
DataType=0x0007
AccessType=rw
DefaultValue=$NODEID+0x200

[607A]
ParameterName=Target position
DataType=0x0004
AccessType=rww
DefaultValue=0
PDOMapping=1
LowLimit=-1000
HighLimit=0x7FFFFFFF

[6098]
ParameterName=Homing method
DataType=0x0002
AccessType=rw
DefaultValue=-1
";

    fn node() -> NodeId {
        NodeId::new(3).unwrap()
    }

    #[test]
    fn reads_objects_sub_indices_node_id_defaults_and_limits() {
        let od = ObjectDictionary::from_eds("drive.eds", EDS, node()).unwrap();
        assert_eq!(
            od.variable(0x1000, 0).unwrap().default,
            vec![0x92, 0x01, 0x02, 0x00]
        );
        assert_eq!(
            od.variable(0x1400, 1).unwrap().default,
            0x203u32.to_le_bytes()
        );
        assert_eq!(od.variable(0x1400, 5), Err(AbortCode::NO_SUBINDEX));
        assert_eq!(od.variable(0x2000, 0), Err(AbortCode::NO_OBJECT));
        assert_eq!(od.variable(0x6098, 0).unwrap().default, vec![0xFF]);
        assert_eq!(od.device_info["productname"], "Drive");
        let tp = od.variable(0x607A, 0).unwrap();
        assert!(tp.pdo_mappable);
        assert_eq!(tp.check_write(&(-5i32).to_le_bytes()), Ok(()));
        assert_eq!(
            tp.check_write(&(-5000i32).to_le_bytes()),
            Err(AbortCode::VALUE_TOO_LOW)
        );
        assert_eq!(tp.check_write(&[1, 2]), Err(AbortCode::TOO_SHORT));
        assert_eq!(
            od.variable(0x1000, 0).unwrap().check_write(&[0; 4]),
            Err(AbortCode::READ_ONLY)
        );
        assert_eq!(decode_int(DataType::Integer16, &[0xFE, 0xFF]), Some(-2));
        assert_eq!(
            decode_int(DataType::Unsigned16, &[0xFE, 0xFF]),
            Some(0xFFFE)
        );
    }

    #[test]
    fn errors_name_file_line_section_and_key() {
        let bad = EDS.replace("DataType=0x0004", "DataType=0x0099");
        let e = ObjectDictionary::from_eds("drive.eds", &bad, node())
            .unwrap_err()
            .to_string();
        assert_eq!(e, "drive.eds:32: key `[607A] DataType`: `0x0099` is not a supported CiA 301 basic data type");
        let bad = EDS.replace("AccessType=rww", "AccessType=sometimes");
        let e = ObjectDictionary::from_eds("drive.eds", &bad, node())
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("drive.eds:33: key `[607A] AccessType`"),
            "{e}"
        );
        let bad = EDS.replace("DefaultValue=-1", "DefaultValue=300");
        let e = ObjectDictionary::from_eds("drive.eds", &bad, node())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains(":43: key `[6098] DefaultValue`: `300` is not a valid Integer8"),
            "{e}"
        );
        let bad = EDS.replace(
            "[1400sub0]\nParameterName=Highest sub-index supported\n",
            "[1400sub0]\n",
        );
        let e = ObjectDictionary::from_eds("drive.eds", &bad, node())
            .unwrap_err()
            .to_string();
        assert!(e.contains("key `[1400sub0] ParameterName`: missing"), "{e}");
        let e = ObjectDictionary::from_eds(
            "x.eds",
            "[1000]\nParameterName=a\nDataType=7\nAccessType=ro\nwhat\n",
            node(),
        )
        .unwrap_err()
        .to_string();
        assert!(e.starts_with("x.eds:5:"), "{e}");
        let e = ObjectDictionary::from_eds(
            "x.eds",
            "[2000]\nParameterName=a\nDataType=7\nAccessType=ro\n",
            node(),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("0x1000 (device type) is missing"), "{e}");
    }
}
