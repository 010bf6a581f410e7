//! Just enough GenICam to drive a camera: resolve a feature name through `pValue` links
//! to its register (address, length, endianness, bit field), read enumeration entries
//! and command values. Covers the node kinds cameras and Aravis's fake camera use for
//! the features this driver touches (Integer, Enumeration, Command, Float over IntReg,
//! MaskedIntReg, FloatReg, StringReg, constant `<Value>`); anything else (`pAddress`,
//! `pIndex`, SwissKnife formulas) is reported by name rather than guessed.

/// Where a feature's value lives.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Location {
    Register {
        address: u32,
        length: u32,
        little_endian: bool,
        /// (shift, width) of a MaskedIntReg field inside the register.
        field: Option<(u32, u32)>,
        float: bool,
    },
    Constant(i64),
}

/// Most `pIndex` selectors resolved inside one another (GenICam nests one or two).
const MAX_DEPTH: usize = 8;

/// (shift, width) of a MaskedIntReg field from its LSB and MSB bit numbers (bit 0 is
/// the least significant in LittleEndian registers, the most significant in BigEndian
/// ones), or `None` if the field is not inside the `length`-byte register.
fn bit_field(lsb: i64, msb: i64, length: u32, little_endian: bool) -> Option<(u32, u32)> {
    let bits = i64::from(length) * 8;
    let inside = |b: i64| (0..bits).contains(&b);
    if !inside(lsb) || !inside(msb) {
        return None;
    }
    let (shift, width) = if little_endian {
        (lsb, msb - lsb + 1)
    } else {
        (bits - 1 - lsb, lsb - msb + 1)
    };
    (width >= 1).then_some((shift as u32, width as u32))
}

/// A parsed GenICam description (the XML text, searched on demand).
pub struct GenICam {
    xml: String,
}

fn parse_int(s: &str) -> Option<i64> {
    let s = s.trim();
    if let Some(h) = s.strip_prefix("0x").or_else(|| s.strip_prefix("0X")) {
        i64::from_str_radix(h, 16).ok()
    } else {
        s.parse().ok()
    }
}

/// The text of the first `<tag>...</tag>` directly inside `body`, outside any nested
/// `EnumEntry` (whose own `Value`s would otherwise be mistaken for the node's).
fn child<'a>(body: &'a str, tag: &str) -> Option<&'a str> {
    let open = format!("<{tag}>");
    let close = format!("</{tag}>");
    let mut rest = body;
    let mut offset = 0;
    loop {
        let i = rest.find(&open)?;
        let before = &body[..offset + i];
        let inside_entry =
            before.matches("<EnumEntry").count() > before.matches("</EnumEntry>").count();
        let start = i + open.len();
        let end = rest[start..].find(&close)? + start;
        if !inside_entry {
            return Some(rest[start..end].trim());
        }
        offset += end;
        rest = &rest[end..];
    }
}

impl GenICam {
    pub fn new(xml: String) -> Self {
        Self { xml }
    }

    /// The element named `name`: (tag, body).
    fn node(&self, name: &str) -> Option<(&str, &str)> {
        let key = format!("Name=\"{name}\"");
        let mut from = 0;
        while let Some(i) = self.xml[from..].find(&key) {
            let at = from + i;
            from = at + key.len();
            let lt = self.xml[..at].rfind('<')?;
            let tag_end = self.xml[lt + 1..].find(|c: char| c.is_whitespace())? + lt + 1;
            let tag = &self.xml[lt + 1..tag_end];
            if tag == "EnumEntry" || tag.starts_with('/') {
                continue;
            }
            let body_start = self.xml[at..].find('>')? + at + 1;
            let close = format!("</{tag}>");
            let body_end = self.xml[body_start..].find(&close)? + body_start;
            return Some((tag, &self.xml[body_start..body_end]));
        }
        None
    }

    pub fn has(&self, name: &str) -> bool {
        self.node(name).is_some()
    }

    /// Resolves `feature` to its register or constant. The XML is the camera's: a
    /// register comes back only if it is 1 to 8 bytes inside the 32-bit address space,
    /// with its bit field inside it; link chains and index selectors are bounded.
    pub fn locate(&self, feature: &str) -> Result<Location, String> {
        self.locate_at(feature, 0)
    }

    fn locate_at(&self, feature: &str, depth: usize) -> Result<Location, String> {
        if depth > MAX_DEPTH {
            return Err(format!(
                "`{feature}`: pIndex selectors nested too deep (more than {MAX_DEPTH}; a loop?)"
            ));
        }
        let mut name = feature.to_string();
        for _ in 0..8 {
            let (tag, body) = self
                .node(&name)
                .ok_or_else(|| format!("the camera's GenICam XML has no node `{name}`"))?;
            if let Some(next) = child(body, "pValue") {
                name = next.to_string();
                continue;
            }
            if let Some(addr) = child(body, "Address") {
                if child(body, "pAddress").is_some() {
                    return Err(format!(
                        "`{feature}` (node `{name}`) uses a computed address (pAddress), which this driver does not evaluate"
                    ));
                }
                let address =
                    parse_int(addr).ok_or_else(|| format!("`{name}`: bad Address `{addr}`"))?;
                let length = child(body, "Length").and_then(parse_int).unwrap_or(4);
                if !(1..=8).contains(&length) {
                    return Err(format!(
                        "`{feature}` (node `{name}`): register length {length} bytes (this driver reads 1 to 8)"
                    ));
                }
                let length = length as u32;
                // `<pIndex Offset="k">Selector</pIndex>`: address + k * selector, when the
                // selector is a constant (as in Aravis's fake camera).
                let address = match body.find("<pIndex") {
                    None => address,
                    Some(i) => {
                        let open_end =
                            body[i..].find('>').map(|e| e + i + 1).ok_or("bad pIndex")?;
                        let tag = &body[i..open_end];
                        let offset = tag
                            .split("Offset=\"")
                            .nth(1)
                            .and_then(|r| r.split('"').next())
                            .and_then(parse_int)
                            .unwrap_or(length as i64);
                        let close = body[open_end..]
                            .find("</pIndex>")
                            .map(|e| e + open_end)
                            .ok_or("bad pIndex")?;
                        let selector = body[open_end..close].trim();
                        match self.locate_at(selector, depth + 1)? {
                            Location::Constant(v) => offset
                                .checked_mul(v)
                                .and_then(|o| o.checked_add(address))
                                .unwrap_or(i64::MIN),
                            Location::Register { .. } => {
                                return Err(format!(
                                    "`{feature}` (node `{name}`) is indexed by the register `{selector}`, which this driver does not evaluate"
                                ))
                            }
                        }
                    }
                };
                let address = u32::try_from(address).map_err(|_| {
                    format!(
                        "`{feature}` (node `{name}`): address {address:#X} (after pIndex) is outside the 32-bit address space"
                    )
                })?;
                let little_endian = child(body, "Endianess") == Some("LittleEndian");
                let field = if tag == "MaskedIntReg" {
                    let (lsb, msb) =
                        match (child(body, "LSB"), child(body, "MSB"), child(body, "Bit")) {
                            (Some(l), Some(m), _) => {
                                (parse_int(l).unwrap_or(0), parse_int(m).unwrap_or(0))
                            }
                            (_, _, Some(b)) => {
                                let b = parse_int(b).unwrap_or(0);
                                (b, b)
                            }
                            _ => {
                                return Err(format!(
                                    "`{name}`: MaskedIntReg without LSB/MSB or Bit"
                                ))
                            }
                        };
                    Some(bit_field(lsb, msb, length, little_endian).ok_or_else(|| {
                        format!(
                            "`{feature}` (node `{name}`): MaskedIntReg field LSB {lsb}, MSB {msb} is not inside its {length}-byte {} register",
                            if little_endian { "LittleEndian" } else { "BigEndian" }
                        )
                    })?)
                } else {
                    None
                };
                return Ok(Location::Register {
                    address,
                    length,
                    little_endian,
                    field,
                    float: tag == "FloatReg",
                });
            }
            if let Some(v) = child(body, "Value") {
                return parse_int(v)
                    .map(Location::Constant)
                    .ok_or_else(|| format!("`{name}`: constant `{v}` is not an integer"));
            }
            return Err(format!(
                "`{feature}` (node `{tag} {name}`) is neither a register nor a constant this driver can resolve"
            ));
        }
        Err(format!("`{feature}`: pValue chain too long"))
    }

    /// The value of entry `entry` of enumeration `feature`.
    pub fn enum_value(&self, feature: &str, entry: &str) -> Result<i64, String> {
        let (_, body) = self
            .node(feature)
            .ok_or_else(|| format!("the camera's GenICam XML has no node `{feature}`"))?;
        let key = format!("<EnumEntry Name=\"{entry}\"");
        let i = body
            .find(&key)
            .ok_or_else(|| format!("`{feature}` has no entry `{entry}`"))?;
        let end = body[i..]
            .find("</EnumEntry>")
            .map(|e| e + i)
            .unwrap_or(body.len());
        let v = &body[i..end];
        let s = v
            .find("<Value>")
            .ok_or_else(|| format!("`{feature}::{entry}` has no Value"))?
            + 7;
        let e = v[s..].find("</Value>").map(|e| e + s).unwrap_or(v.len());
        parse_int(&v[s..e]).ok_or_else(|| format!("`{feature}::{entry}`: bad Value"))
    }

    /// The name of the entry of `feature` whose value is `value`.
    pub fn enum_name(&self, feature: &str, value: i64) -> Option<String> {
        let (_, body) = self.node(feature)?;
        let mut rest = body;
        while let Some(i) = rest.find("<EnumEntry Name=\"") {
            let s = i + 17;
            let e = rest[s..].find('"')? + s;
            let name = &rest[s..e];
            let end = rest[e..].find("</EnumEntry>")? + e;
            if let Some(v) =
                child(&rest[e..end].replace("<EnumEntry", ""), "Value").and_then(parse_int)
            {
                if v == value {
                    return Some(name.to_string());
                }
            }
            rest = &rest[end..];
        }
        None
    }

    /// The value a command node writes (`CommandValue`, default 1).
    pub fn command_value(&self, feature: &str) -> Result<i64, String> {
        let (_, body) = self
            .node(feature)
            .ok_or_else(|| format!("the camera's GenICam XML has no node `{feature}`"))?;
        Ok(child(body, "CommandValue").and_then(parse_int).unwrap_or(1))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const XML: &str = r#"<RegisterDescription>
  <Enumeration Name="TriggerMode" NameSpace="Standard">
    <EnumEntry Name="Off"><Value>0</Value></EnumEntry>
    <EnumEntry Name="On"><Value>1</Value></EnumEntry>
    <pValue>TriggerModeRegister</pValue>
  </Enumeration>
  <IntReg Name="TriggerModeRegister"><Address>0x300</Address><Length>4</Length><Endianess>BigEndian</Endianess></IntReg>
  <Command Name="AcquisitionStop"><pValue>Acq</pValue><CommandValue>0</CommandValue></Command>
  <IntReg Name="Acq"><Address>0x124</Address><Length>4</Length></IntReg>
  <Integer Name="Sel"><Value>2</Value></Integer>
  <IntReg Name="Src"><Address>0x304</Address><pIndex Offset="0x20">Sel</pIndex><Length>4</Length></IntReg>
  <MaskedIntReg Name="Ps"><Address>0xd04</Address><Length>4</Length><LSB>31</LSB><MSB>16</MSB><Endianess>BigEndian</Endianess></MaskedIntReg>
</RegisterDescription>"#;

    #[test]
    fn features_resolve_like_the_fake_camera_declares_them() {
        let g = GenICam::new(XML.into());
        assert_eq!(
            g.locate("TriggerMode").unwrap(),
            Location::Register {
                address: 0x300,
                length: 4,
                little_endian: false,
                field: None,
                float: false
            }
        );
        assert_eq!(g.enum_value("TriggerMode", "On").unwrap(), 1);
        assert_eq!(g.enum_name("TriggerMode", 0).as_deref(), Some("Off"));
        assert_eq!(g.command_value("AcquisitionStop").unwrap(), 0);
        assert_eq!(g.locate("Sel").unwrap(), Location::Constant(2));
        assert!(matches!(
            g.locate("Src").unwrap(),
            Location::Register { address: 0x344, .. }
        ));
        assert!(matches!(
            g.locate("Ps").unwrap(),
            Location::Register {
                field: Some((0, 16)),
                ..
            }
        ));
        assert!(g.locate("Nope").unwrap_err().contains("`Nope`"));
        assert!(g
            .enum_value("TriggerMode", "Maybe")
            .unwrap_err()
            .contains("Maybe"));
    }

    #[test]
    fn our_emulator_xml_resolves() {
        let g = GenICam::new(include_str!("../../../config/gige/sim-camera.xml").into());
        for f in [
            "Width",
            "Height",
            "PixelFormat",
            "PayloadSize",
            "TriggerSoftware",
            "AcquisitionStart",
        ] {
            assert!(matches!(g.locate(f), Ok(Location::Register { .. })), "{f}");
        }
        assert_eq!(g.enum_value("PixelFormat", "Mono16").unwrap(), 0x0110_0007);
        assert!(matches!(
            g.locate("ExposureTime"),
            Ok(Location::Register { float: true, .. })
        ));
    }

    #[test]
    fn hostile_register_descriptions_are_errors_not_panics() {
        let xml = r#"<RegisterDescription>
  <MaskedIntReg Name="Inverted"><Address>0x10</Address><Length>4</Length><LSB>9</LSB><MSB>2</MSB><Endianess>LittleEndian</Endianess></MaskedIntReg>
  <MaskedIntReg Name="Outside"><Address>0x10</Address><Length>4</Length><Bit>40</Bit></MaskedIntReg>
  <MaskedIntReg Name="Negative"><Address>0x10</Address><Length>4</Length><LSB>-1</LSB><MSB>0</MSB></MaskedIntReg>
  <IntReg Name="Loop"><Address>0x20</Address><pIndex>Loop</pIndex><Length>4</Length></IntReg>
  <Integer Name="Big"><Value>0x7FFFFFFFFFFFFFFF</Value></Integer>
  <IntReg Name="Far"><Address>0x30</Address><pIndex Offset="0x7FFFFFFFFFFFFFFF">Big</pIndex><Length>4</Length></IntReg>
  <IntReg Name="Beyond"><Address>0x1FFFFFFFF</Address><Length>4</Length></IntReg>
  <IntReg Name="Long"><Address>0x40</Address><Length>100</Length></IntReg>
  <IntReg Name="NoLength"><Address>0x40</Address><Length>-4</Length></IntReg>
</RegisterDescription>"#;
        let g = GenICam::new(xml.into());
        for (f, says) in [
            ("Inverted", "LSB 9, MSB 2"),
            ("Outside", "LSB 40, MSB 40"),
            ("Negative", "LSB -1"),
            ("Loop", "too deep"),
            ("Far", "outside the 32-bit address space"),
            ("Beyond", "outside the 32-bit address space"),
            ("Long", "100 bytes"),
            ("NoLength", "-4 bytes"),
        ] {
            let r = std::panic::catch_unwind(|| g.locate(f));
            let e = r.unwrap_or_else(|_| panic!("`{f}` panicked")).expect_err(f);
            assert!(e.contains(f) && e.contains(says), "{f}: {e}");
        }
    }
}
