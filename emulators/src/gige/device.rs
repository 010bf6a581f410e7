//! The GigE Vision camera's control side, sans-IO: bootstrap and feature registers, the
//! GenICam XML in device memory, control channel privilege with heartbeat expiry, and
//! the stream channel configuration. The server ([`super::server`]) feeds it datagrams
//! with the sender and the time, sends back the acknowledge it returns, and acts on its
//! [`Event`]s (stream a frame, start or stop continuous acquisition, resend packets).

use protocol::gige::gvcp::{status, Ack, AckBody, Command, CommandPacket};
use protocol::gige::{bootstrap as bs, gvcp, pfnc};
use std::net::{Ipv4Addr, SocketAddr, SocketAddrV4};

/// The GenICam XML served at [`XML_ADDRESS`] (kept in `config/gige/`).
pub const XML: &str = include_str!("../../../config/gige/sim-camera.xml");
/// Where the XML lives in device memory (as in Aravis's fake camera).
pub const XML_ADDRESS: u32 = 0x10000;
/// File name in the `Local:` URL.
pub const XML_FILE: &str = "sim-camera.xml";

/// Feature registers (must match `config/gige/sim-camera.xml`).
pub mod reg {
    pub const BASE: u32 = 0x20000;
    pub const WIDTH: u32 = BASE;
    pub const HEIGHT: u32 = BASE + 0x04;
    pub const PIXEL_FORMAT: u32 = BASE + 0x08;
    pub const PAYLOAD_SIZE: u32 = BASE + 0x0C;
    pub const OFFSET_X: u32 = BASE + 0x10;
    pub const OFFSET_Y: u32 = BASE + 0x14;
    /// 0 Continuous, 1 SingleFrame, 2 MultiFrame.
    pub const ACQUISITION_MODE: u32 = BASE + 0x20;
    pub const ACQUISITION_START: u32 = BASE + 0x24;
    pub const ACQUISITION_STOP: u32 = BASE + 0x28;
    pub const TRIGGER_SELECTOR: u32 = BASE + 0x30;
    /// 0 Off, 1 On.
    pub const TRIGGER_MODE: u32 = BASE + 0x34;
    /// 0 Software, 1 Line0.
    pub const TRIGGER_SOURCE: u32 = BASE + 0x38;
    pub const TRIGGER_SOFTWARE: u32 = BASE + 0x3C;
    pub const TRIGGER_ACTIVATION: u32 = BASE + 0x40;
    /// f32 bits.
    pub const EXPOSURE_TIME: u32 = BASE + 0x50;
    /// f32 bits.
    pub const GAIN: u32 = BASE + 0x54;
    /// f32 bits.
    pub const ACQUISITION_FRAME_RATE: u32 = BASE + 0x58;
    pub const TL_PARAMS_LOCKED: u32 = BASE + 0x5C;
    pub const END: u32 = BASE + 0x60;
}

/// Identity and behaviour of the emulated camera.
#[derive(Clone, Debug)]
pub struct GigeConfig {
    pub vendor: String,
    pub model: String,
    pub serial: String,
    pub user_name: String,
    /// Heartbeat timeout the device starts with (ms; clients may change it).
    pub heartbeat_timeout_ms: u32,
    /// Continuous-mode frame rate the device starts with.
    pub frame_rate_hz: f32,
    /// Drop every `n`-th payload packet of each frame's first transmission (resends are
    /// delivered unless `loss_on_resend`): the lossy link of the bad-input tests.
    pub drop_every: Option<u32>,
    /// Drop the resent packets too, so a frame can only arrive incomplete.
    pub loss_on_resend: bool,
    /// Serve the GenICam XML zipped (`Local:sim-camera.zip;...`), as many real cameras do.
    pub zip_xml: bool,
    /// The device clock behind frame timestamps: wall time scaled by `k` (`k` = 1: real
    /// time), declared as 1e9 * k ticks per wall second in the tick frequency
    /// registers; or, unconstrained, the simulated machine's clock in ns.
    pub clock: world::Clock,
}

impl GigeConfig {
    /// Timestamp ticks per wall second (the bootstrap's tick frequency).
    pub fn tick_frequency_hz(&self) -> u64 {
        match self.clock {
            world::Clock::Scaled(k) => (1e9 * k).round() as u64,
            world::Clock::Unconstrained => 1_000_000_000,
        }
    }
}

impl Default for GigeConfig {
    fn default() -> Self {
        Self {
            vendor: "XYGateway".into(),
            model: "SimMono".into(),
            serial: "SIM0001".into(),
            user_name: String::new(),
            heartbeat_timeout_ms: 3000,
            frame_rate_hz: 10.0,
            drop_every: None,
            loss_on_resend: false,
            zip_xml: false,
            clock: world::Clock::Scaled(1.0),
        }
    }
}

/// What the server must do after a command.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Event {
    /// AcquisitionStart: in continuous mode without trigger, stream at the frame rate;
    /// in SingleFrame mode without trigger, send one frame.
    AcquisitionStarted,
    AcquisitionStopped,
    /// TriggerSoftware while acquiring in software trigger mode: expose one frame now.
    Trigger,
    Resend {
        block_id: u16,
        first: u32,
        last: u32,
    },
    /// The controller left (closed, or its heartbeat expired): stop streaming.
    ControlReleased,
}

/// The register file and control state.
pub struct GigeDevice {
    cfg: GigeConfig,
    mem: Vec<u8>,
    xml: Vec<u8>,
    controller: Option<SocketAddr>,
    last_heard_ms: u64,
    acquiring: bool,
}

const MEM_END: usize = 0x1000;

fn put_str(mem: &mut [u8], at: u32, len: usize, s: &str) {
    let b = s.as_bytes();
    let n = b.len().min(len - 1);
    mem[at as usize..at as usize + n].copy_from_slice(&b[..n]);
}

impl GigeDevice {
    /// A camera of `width` x `height` pixels and `bit_depth` 8 or 16, answering at `ip`.
    pub fn new(cfg: GigeConfig, width: u32, height: u32, bit_depth: u8, ip: Ipv4Addr) -> Self {
        let mut d = Self {
            mem: vec![0; MEM_END + (reg::END - reg::BASE) as usize],
            xml: if cfg.zip_xml {
                protocol::gige::zip::store_one(XML_FILE, XML.as_bytes(), true)
            } else {
                XML.as_bytes().to_vec()
            },
            controller: None,
            last_heard_ms: 0,
            acquiring: false,
            cfg,
        };
        // Pad the XML to a multiple of 4 so READMEMs of whole words cover it.
        while d.xml.len() & 3 != 0 {
            d.xml.push(0);
        }
        let pf = if bit_depth == 16 {
            pfnc::MONO16
        } else {
            pfnc::MONO8
        };
        let w = |d: &mut Self, a: u32, v: u32| d.set(a, v);
        w(&mut d, bs::VERSION, 2 << 16);
        // Big-endian, transmitter, UTF-8.
        w(&mut d, bs::DEVICE_MODE, 0x8000_0001);
        // A locally administered MAC.
        w(&mut d, bs::MAC_HIGH, 0x0002);
        w(&mut d, bs::MAC_LOW, 0x5845_4701);
        w(&mut d, bs::IP_CONFIG_SUPPORTED, 0x7);
        w(&mut d, bs::IP_CONFIG_CURRENT, 0x1);
        w(&mut d, bs::CURRENT_IP, u32::from(ip));
        w(&mut d, bs::SUBNET_MASK, 0xFF00_0000);
        w(&mut d, bs::NUM_NETWORK_INTERFACES, 1);
        w(&mut d, bs::NUM_STREAM_CHANNELS, 1);
        w(
            &mut d,
            bs::GVCP_CAPABILITY,
            bs::CAP_WRITEMEM | bs::CAP_PACKETRESEND | 0x8000_0000 | 0x4000_0000,
        );
        let hb = d.cfg.heartbeat_timeout_ms;
        w(&mut d, bs::HEARTBEAT_TIMEOUT, hb);
        // Timestamp ticks: device-clock nanoseconds (see `GigeConfig::clock`).
        let ticks = d.cfg.tick_frequency_hz();
        w(&mut d, bs::TICK_FREQUENCY_HIGH, (ticks >> 32) as u32);
        w(&mut d, bs::TICK_FREQUENCY_LOW, ticks as u32);
        w(&mut d, bs::SCPS0, 1500);
        let url = if d.cfg.zip_xml {
            let zipped = protocol::gige::zip::store_one(XML_FILE, XML.as_bytes(), true);
            format!("Local:sim-camera.zip;{XML_ADDRESS:X};{:X}", zipped.len())
        } else {
            format!("Local:{XML_FILE};{XML_ADDRESS:X};{:X}", XML.len())
        };
        put_str(&mut d.mem, bs::FIRST_URL, bs::URL_LEN, &url);
        put_str(&mut d.mem, bs::SECOND_URL, bs::URL_LEN, &url);
        let c = d.cfg.clone();
        put_str(&mut d.mem, bs::MANUFACTURER, 32, &c.vendor);
        put_str(&mut d.mem, bs::MODEL, 32, &c.model);
        put_str(&mut d.mem, bs::DEVICE_VERSION, 32, "1.0 (emulated)");
        put_str(
            &mut d.mem,
            bs::MANUFACTURER_INFO,
            48,
            "simulated machine camera",
        );
        put_str(&mut d.mem, bs::SERIAL_NUMBER, 16, &c.serial);
        put_str(&mut d.mem, bs::USER_NAME, 16, &c.user_name);
        w(&mut d, reg::WIDTH, width);
        w(&mut d, reg::HEIGHT, height);
        w(&mut d, reg::PIXEL_FORMAT, pf);
        w(
            &mut d,
            reg::PAYLOAD_SIZE,
            width * height * pfnc::bits_per_pixel(pf) / 8,
        );
        w(&mut d, reg::TRIGGER_MODE, 0);
        w(&mut d, reg::EXPOSURE_TIME, 2000f32.to_bits());
        w(&mut d, reg::GAIN, 0f32.to_bits());
        w(
            &mut d,
            reg::ACQUISITION_FRAME_RATE,
            c.frame_rate_hz.to_bits(),
        );
        d
    }

    /// Feature registers live in a small second block; map an address to a mem index.
    fn index(addr: u32) -> Option<usize> {
        if (addr as usize) < MEM_END {
            Some(addr as usize)
        } else if (reg::BASE..reg::END).contains(&addr) {
            Some(MEM_END + (addr - reg::BASE) as usize)
        } else {
            None
        }
    }

    fn set(&mut self, addr: u32, v: u32) {
        let i = Self::index(addr).expect("register in the map");
        self.mem[i..i + 4].copy_from_slice(&v.to_be_bytes());
    }

    /// A register's value (for the server and tests).
    pub fn get(&self, addr: u32) -> u32 {
        let i = Self::index(addr).expect("register in the map");
        u32::from_be_bytes(self.mem[i..i + 4].try_into().expect("4 bytes"))
    }

    pub fn config(&self) -> &GigeConfig {
        &self.cfg
    }
    pub fn width(&self) -> u32 {
        self.get(reg::WIDTH)
    }
    pub fn height(&self) -> u32 {
        self.get(reg::HEIGHT)
    }
    pub fn pixel_format(&self) -> u32 {
        self.get(reg::PIXEL_FORMAT)
    }
    pub fn packet_size(&self) -> u32 {
        self.get(bs::SCPS0) & 0xFFFF
    }
    pub fn acquiring(&self) -> bool {
        self.acquiring
    }
    /// Frames wait for TriggerSoftware (TriggerMode On, source Software).
    pub fn software_triggered(&self) -> bool {
        self.get(reg::TRIGGER_MODE) == 1 && self.get(reg::TRIGGER_SOURCE) == 0
    }
    pub fn acquisition_mode(&self) -> u32 {
        self.get(reg::ACQUISITION_MODE)
    }
    pub fn frame_rate_hz(&self) -> f32 {
        f32::from_bits(self.get(reg::ACQUISITION_FRAME_RATE))
    }
    pub fn exposure_us(&self) -> f32 {
        f32::from_bits(self.get(reg::EXPOSURE_TIME))
    }
    pub fn gain_db(&self) -> f32 {
        f32::from_bits(self.get(reg::GAIN))
    }
    /// Where frames go: SCDA0:SCP0, once a controller has opened the channel.
    pub fn stream_destination(&self) -> Option<SocketAddr> {
        let port = (self.get(bs::SCP0) & 0xFFFF) as u16;
        if port == 0 || self.controller.is_none() {
            return None;
        }
        let ip = Ipv4Addr::from(self.get(bs::SCDA0));
        Some(SocketAddr::V4(SocketAddrV4::new(ip, port)))
    }
    /// The stream socket's source port, reported in SCSP0.
    pub fn set_stream_source_port(&mut self, port: u16) {
        self.set(bs::SCSP0, port as u32);
    }

    fn heartbeat_expired(&self, now_ms: u64) -> bool {
        let disabled = self.get(bs::GVCP_CONFIG) & bs::GVCP_CONFIG_HEARTBEAT_DISABLE != 0;
        !disabled
            && now_ms.saturating_sub(self.last_heard_ms) > self.get(bs::HEARTBEAT_TIMEOUT) as u64
    }

    /// Drops a controller whose heartbeat expired; returns the events that causes.
    pub fn poll(&mut self, now_ms: u64) -> Vec<Event> {
        if self.controller.is_some() && self.heartbeat_expired(now_ms) {
            self.release()
        } else {
            Vec::new()
        }
    }

    fn release(&mut self) -> Vec<Event> {
        self.controller = None;
        self.set(bs::CCP, 0);
        self.set(bs::SCP0, 0);
        let was = std::mem::replace(&mut self.acquiring, false);
        let mut ev = vec![Event::ControlReleased];
        if was {
            ev.push(Event::AcquisitionStopped);
        }
        ev
    }

    /// Milliseconds until the controller's heartbeat would expire (for the server's timer).
    pub fn heartbeat_deadline_ms(&self) -> Option<u64> {
        self.controller
            .map(|_| self.last_heard_ms + self.get(bs::HEARTBEAT_TIMEOUT) as u64 + 1)
    }

    /// Handles one datagram from `from` at `now_ms`: the acknowledge to send back (if
    /// the sender asked for one) and what the server must do.
    pub fn handle(
        &mut self,
        from: SocketAddr,
        now_ms: u64,
        datagram: &[u8],
    ) -> (Option<Vec<u8>>, Vec<Event>) {
        let mut events = self.poll(now_ms);
        let pkt = match CommandPacket::decode(datagram) {
            Ok(p) => p,
            Err(gvcp::GvcpError::UnknownCommand(code)) if datagram.len() >= 8 => {
                let req = u16::from_be_bytes([datagram[6], datagram[7]]);
                return (
                    Some(Ack::error(code, status::NOT_IMPLEMENTED, req).encode()),
                    events,
                );
            }
            // Not a GVCP command: a real device ignores it.
            Err(_) => return (None, events),
        };
        let is_controller = self.controller == Some(from);
        if is_controller {
            self.last_heard_ms = now_ms;
        }
        let code = pkt.command.code();
        let (st, body) = match pkt.command {
            Command::Discovery => (
                status::SUCCESS,
                Some(AckBody::Discovery(self.mem[..bs::DISCOVERY_LEN].to_vec())),
            ),
            Command::ReadReg(addrs) => {
                let mut vals = Vec::with_capacity(addrs.len());
                let mut st = status::SUCCESS;
                for a in addrs {
                    match self.read_reg(a) {
                        Ok(v) => vals.push(v),
                        Err(s) => {
                            st = s;
                            break;
                        }
                    }
                }
                if st == status::SUCCESS {
                    (st, Some(AckBody::ReadReg(vals)))
                } else {
                    (st, None)
                }
            }
            Command::WriteReg(pairs) => {
                let mut st = status::SUCCESS;
                let mut index = 0u16;
                for (i, (a, v)) in pairs.iter().enumerate() {
                    index = i as u16;
                    match self.write_reg(from, now_ms, *a, *v, &mut events) {
                        Ok(()) => {}
                        Err(s) => {
                            st = s;
                            break;
                        }
                    }
                }
                (st, Some(AckBody::WriteReg { index }))
            }
            Command::ReadMem { address, count } => match self.read_mem(address, count) {
                Ok(data) => (status::SUCCESS, Some(AckBody::ReadMem { address, data })),
                Err(s) => (s, None),
            },
            Command::WriteMem { address, data } => {
                let st = self.write_mem(from, now_ms, address, &data, &mut events);
                (st, Some(AckBody::WriteMem { index: 0 }))
            }
            Command::PacketResend {
                block_id,
                first,
                last,
                ..
            } => {
                // Aravis asks from its stream socket, not the control one: any port of
                // the controlling host may ask.
                if self.controller.map(|c| c.ip()) == Some(from.ip()) {
                    events.push(Event::Resend {
                        block_id,
                        first,
                        last,
                    });
                }
                // PACKETRESEND has no acknowledge.
                return (None, events);
            }
        };
        if pkt.flags & gvcp::FLAG_ACK_REQUIRED == 0 {
            return (None, events);
        }
        let ack = match (st, body) {
            (status::SUCCESS, Some(body)) => Ack {
                status: st,
                ack_id: pkt.req_id,
                body,
            },
            (st, Some(AckBody::WriteReg { index })) => Ack {
                status: st,
                ack_id: pkt.req_id,
                body: AckBody::Other {
                    code: code + 1,
                    payload: [0, 0, (index >> 8) as u8, index as u8].to_vec(),
                },
            },
            (st, _) => Ack::error(code, st, pkt.req_id),
        };
        (Some(ack.encode()), events)
    }

    fn read_reg(&self, a: u32) -> Result<u32, u16> {
        if a & 3 != 0 {
            return Err(status::BAD_ALIGNMENT);
        }
        match Self::index(a) {
            Some(_) => Ok(self.get(a)),
            None => Err(status::INVALID_ADDRESS),
        }
    }

    fn read_mem(&self, address: u32, count: u16) -> Result<Vec<u8>, u16> {
        let n = count as usize;
        if address & 3 != 0 || n & 3 != 0 {
            return Err(status::BAD_ALIGNMENT);
        }
        if n > gvcp::MAX_MEM_BLOCK {
            return Err(status::INVALID_PARAMETER);
        }
        let a = address as usize;
        let x = XML_ADDRESS as usize;
        if a >= x && a + n <= x + self.xml.len() {
            return Ok(self.xml[a - x..a - x + n].to_vec());
        }
        // A read may run past the XML's end (rounded up): pad with zeros like Aravis.
        if a >= x && a < x + self.xml.len() {
            let mut v = self.xml[a - x..].to_vec();
            v.resize(n, 0);
            return Ok(v);
        }
        match (Self::index(address), Self::index(address + n as u32 - 4)) {
            (Some(i), Some(j)) if j == i + n - 4 => Ok(self.mem[i..i + n].to_vec()),
            _ => Err(status::INVALID_ADDRESS),
        }
    }

    fn write_mem(
        &mut self,
        from: SocketAddr,
        now_ms: u64,
        address: u32,
        data: &[u8],
        events: &mut Vec<Event>,
    ) -> u16 {
        if address & 3 != 0 || data.len() & 3 != 0 || data.is_empty() {
            return status::BAD_ALIGNMENT;
        }
        for (k, w) in data.chunks(4).enumerate() {
            let v = u32::from_be_bytes(w.try_into().expect("4 bytes"));
            let a = address + 4 * k as u32;
            // The user name string is the only writable multi-word region.
            if (bs::USER_NAME..bs::USER_NAME + 16).contains(&a) {
                if !self.may_write(from) {
                    return status::ACCESS_DENIED;
                }
                self.set(a, v);
                continue;
            }
            if let Err(s) = self.write_reg(from, now_ms, a, v, events) {
                return s;
            }
        }
        status::SUCCESS
    }

    fn may_write(&self, from: SocketAddr) -> bool {
        self.controller == Some(from)
    }

    fn write_reg(
        &mut self,
        from: SocketAddr,
        now_ms: u64,
        a: u32,
        v: u32,
        events: &mut Vec<Event>,
    ) -> Result<(), u16> {
        if a & 3 != 0 {
            return Err(status::BAD_ALIGNMENT);
        }
        if a == bs::CCP {
            return match self.controller {
                Some(c) if c != from => Err(status::ACCESS_DENIED),
                _ if v & (bs::CCP_CONTROL | bs::CCP_EXCLUSIVE) == 0 => {
                    if self.controller.is_some() {
                        events.extend(self.release());
                    }
                    Ok(())
                }
                _ => {
                    self.controller = Some(from);
                    self.last_heard_ms = now_ms;
                    self.set(bs::CCP, v & 0x7);
                    Ok(())
                }
            };
        }
        if Self::index(a).is_none() {
            return Err(status::INVALID_ADDRESS);
        }
        if !self.may_write(from) {
            return Err(status::ACCESS_DENIED);
        }
        match a {
            bs::HEARTBEAT_TIMEOUT => self.set(a, v.max(500)),
            bs::GVCP_CONFIG | bs::SCDA0 | bs::SCPD0 => self.set(a, v),
            bs::SCP0 => {
                self.set(a, v & 0xFFFF);
            }
            bs::SCPS0 => {
                // Packet size: keep within what a UDP datagram and our header can carry;
                // bits 31-29 (test packet, don't fragment, big-endian) are not kept.
                let size = (v & 0xFFFF).clamp(576, 65000) & !3;
                self.set(a, size);
            }
            reg::ACQUISITION_MODE => {
                if v > 2 {
                    return Err(status::INVALID_PARAMETER);
                }
                self.set(a, v)
            }
            reg::TRIGGER_SELECTOR | reg::TRIGGER_ACTIVATION => {
                if v != 0 {
                    return Err(status::INVALID_PARAMETER);
                }
                self.set(a, v)
            }
            reg::TRIGGER_MODE | reg::TRIGGER_SOURCE | reg::TL_PARAMS_LOCKED => {
                if v > 1 {
                    return Err(status::INVALID_PARAMETER);
                }
                self.set(a, v)
            }
            reg::EXPOSURE_TIME | reg::GAIN | reg::ACQUISITION_FRAME_RATE => {
                let f = f32::from_bits(v);
                let ok = match a {
                    reg::EXPOSURE_TIME => (10.0..=1e6).contains(&f),
                    reg::GAIN => (0.0..=24.0).contains(&f),
                    _ => (0.1..=200.0).contains(&f),
                };
                if !ok {
                    return Err(status::INVALID_PARAMETER);
                }
                self.set(a, v)
            }
            reg::ACQUISITION_START => {
                if v & 1 == 1 {
                    self.acquiring = true;
                    self.set(reg::TL_PARAMS_LOCKED, 1);
                    events.push(Event::AcquisitionStarted);
                }
            }
            reg::ACQUISITION_STOP => {
                if v & 1 == 1 {
                    self.acquiring = false;
                    self.set(reg::TL_PARAMS_LOCKED, 0);
                    events.push(Event::AcquisitionStopped);
                }
            }
            reg::TRIGGER_SOFTWARE => {
                if v & 1 == 1 && self.acquiring && self.software_triggered() {
                    events.push(Event::Trigger);
                }
            }
            _ => return Err(status::WRITE_PROTECT),
        }
        Ok(())
    }
}

/// The READREG of the control channel privilege, as heartbeats send it (for tests).
pub fn heartbeat_packet(req_id: u16) -> Vec<u8> {
    CommandPacket {
        flags: gvcp::FLAG_ACK_REQUIRED,
        req_id,
        command: Command::ReadReg(vec![bs::CCP]),
    }
    .encode()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dev() -> GigeDevice {
        GigeDevice::new(GigeConfig::default(), 64, 48, 8, Ipv4Addr::LOCALHOST)
    }
    fn cmd(req_id: u16, command: Command) -> Vec<u8> {
        CommandPacket {
            flags: 1,
            req_id,
            command,
        }
        .encode()
    }
    const A: SocketAddr = SocketAddr::V4(SocketAddrV4::new(Ipv4Addr::LOCALHOST, 5000));
    const B: SocketAddr = SocketAddr::V4(SocketAddrV4::new(Ipv4Addr::LOCALHOST, 6000));

    #[test]
    fn discovery_returns_the_bootstrap_block_with_the_address() {
        let mut d = dev();
        let (ack, _) = d.handle(A, 0, &cmd(0xFFFF, Command::Discovery));
        let ack = Ack::decode(&ack.unwrap()).unwrap();
        assert_eq!(ack.ack_id, 0xFFFF);
        let AckBody::Discovery(b) = ack.body else {
            panic!("{ack:?}")
        };
        assert_eq!(b.len(), 0xF8);
        assert_eq!(&b[0x24..0x28], &[127, 0, 0, 1]);
        assert_eq!(&b[0x48..0x51], b"XYGateway");
    }

    #[test]
    fn xml_url_and_xml_are_readable() {
        let mut d = dev();
        let (ack, _) = d.handle(
            A,
            0,
            &cmd(
                1,
                Command::ReadMem {
                    address: 0x200,
                    count: 512,
                },
            ),
        );
        let AckBody::ReadMem { data, .. } = Ack::decode(&ack.unwrap()).unwrap().body else {
            panic!()
        };
        let (file, addr, size) = protocol::gige::parse_local_url(&data).unwrap();
        assert_eq!((file.as_str(), addr), (XML_FILE, XML_ADDRESS));
        assert_eq!(size as usize, XML.len());
        let (ack, _) = d.handle(
            A,
            0,
            &cmd(
                2,
                Command::ReadMem {
                    address: addr,
                    count: 16,
                },
            ),
        );
        let AckBody::ReadMem { data, .. } = Ack::decode(&ack.unwrap()).unwrap().body else {
            panic!()
        };
        assert_eq!(&data, &XML.as_bytes()[..16]);
    }

    #[test]
    fn privilege_guards_writes_and_heartbeat_expiry_releases_it() {
        let mut d = dev();
        let w = |v| cmd(3, Command::WriteReg(vec![(bs::CCP, v)]));
        let st = |a: Option<Vec<u8>>| Ack::decode(&a.unwrap()).unwrap().status;
        // Nobody in control: feature writes are refused.
        let (a, _) = d.handle(
            A,
            0,
            &cmd(4, Command::WriteReg(vec![(reg::TRIGGER_MODE, 1)])),
        );
        assert_eq!(st(a), status::ACCESS_DENIED);
        assert_eq!(st(d.handle(A, 0, &w(2)).0), status::SUCCESS);
        assert_eq!(st(d.handle(B, 10, &w(2)).0), status::ACCESS_DENIED);
        // A heartbeat at 2 s keeps A; silence for longer than 3 s lets B take over.
        d.handle(A, 2000, &heartbeat_packet(5));
        assert_eq!(st(d.handle(B, 4000, &w(2)).0), status::ACCESS_DENIED);
        let (a, ev) = d.handle(B, 5100, &w(2));
        assert_eq!(st(a), status::SUCCESS);
        assert_eq!(ev, vec![Event::ControlReleased]);
    }

    #[test]
    fn read_only_features_are_write_protected_and_trigger_needs_acquisition() {
        let mut d = dev();
        d.handle(A, 0, &cmd(1, Command::WriteReg(vec![(bs::CCP, 2)])));
        let (a, _) = d.handle(A, 0, &cmd(2, Command::WriteReg(vec![(reg::WIDTH, 10)])));
        assert_eq!(
            Ack::decode(&a.unwrap()).unwrap().status,
            status::WRITE_PROTECT
        );
        let (_, ev) = d.handle(
            A,
            0,
            &cmd(3, Command::WriteReg(vec![(reg::TRIGGER_SOFTWARE, 1)])),
        );
        assert!(ev.is_empty());
        let (_, ev) = d.handle(
            A,
            0,
            &cmd(
                4,
                Command::WriteReg(vec![
                    (reg::TRIGGER_MODE, 1),
                    (reg::ACQUISITION_START, 1),
                    (reg::TRIGGER_SOFTWARE, 1),
                ]),
            ),
        );
        assert_eq!(ev, vec![Event::AcquisitionStarted, Event::Trigger]);
        assert_eq!(d.get(reg::PAYLOAD_SIZE), 64 * 48);
    }
}
