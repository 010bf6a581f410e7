//! Writes the seed corpora of the binary formats with the crates' own encoders (and
//! copies the repository's files for the text formats):
//! `cargo run -p fuzz-targets --example seeds`. Existing files are overwritten; the
//! names are stable, so running it again changes nothing.

use fuzz_targets::fuzz_dir;
use protocol::gige::gvcp::{Ack, AckBody, Command, CommandPacket};
use protocol::gige::gvsp::{encode_frame_packet, ImageLeader};
use protocol::gige::{pfnc, zip};
use protocol::modbus::frame::{rtu_frame, Mbap};
use protocol::modbus::{Request, Response};
use protocol::{MonoImage, Pixels};

fn put(target: &str, name: &str, data: &[u8]) {
    let dir = fuzz_dir().join("corpus").join(target);
    std::fs::create_dir_all(&dir).expect("corpus folder");
    std::fs::write(dir.join(name), data).expect("seed file");
}

/// Length-prefixed records, as `fuzz_targets` splits them.
fn records(head: &[u8], rs: &[Vec<u8>]) -> Vec<u8> {
    let mut out = head.to_vec();
    for r in rs {
        assert!(r.len() < 256);
        out.push(r.len() as u8);
        out.extend_from_slice(r);
    }
    out
}

fn copy(target: &str, repo_path: &str, prefix: &[u8]) {
    let root = fuzz_dir().join("../..");
    let text = std::fs::read(root.join(repo_path)).expect("repository file");
    let name = repo_path.rsplit('/').next().expect("file name");
    put(target, name, &[prefix, &text].concat());
}

fn main() {
    // GRBL.
    put(
        "grbl_response",
        "session",
        b"\x03\r\nGrbl 1.1h ['$' for help]\r\nok\r\nerror:20\r\n<Idle|MPos:1.000,2.000,0.000|FS:0,0|WCO:0.000,0.000,0.000>\r\n<Run|WPos:1.0000,-2.5000,0.0000|Bf:15,128|Ln:7|F:500|Pn:XZ|Ov:100,100,100|A:SF>\r\nALARM:1\r\n[MSG:Reset to continue]\r\n[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]\r\n$100=250.000\r\n",
    );
    put(
        "grbl_gcode",
        "program",
        b"G21 G90 G17\nG0 X10 Y5\nG1 X20.5 f500 (cut)\nG2 X30 Y5 I5 J0\nG3 X20 Y5 R5\n$J=G91 X1 F100\nG10 L2 P1 X1\nG92 X0\nM3 S1000\nG4 P0.5 ; dwell\nG20 G1 X1\nM30\n",
    );
    put(
        "nc_program",
        "program",
        b"%\r\nO100 (header)\r\nN10 g1 x1.50 (keep) ; note\r\n/G0 Y2\rG02 X1 Y1 I.5\n%\n",
    );
    // SLCAN.
    put(
        "slcan",
        "both",
        b"\x02O\rS8\rt7FF0\rT1FFFFFFF81122334455667788\rr1238\rt123411223344\rF\rV\rN\rZ1\rM00000000\rm1FFFFFFF\rs031C\r\rz\rZ\rF00\rV1013\rNA123\rt12321122ABCD\r\x07C\r",
    );
    // CANopen SDO: responses for the client, requests for the server.
    put(
        "sdo_client",
        "expedited_upload_then_downloads",
        &records(
            &[0, 8],
            &[
                vec![0x43, 0x64, 0x60, 0x00, 0x01, 0x02, 0x03, 0x04],
                vec![0x60, 0x7A, 0x60, 0x00, 0, 0, 0, 0],
                vec![0x60, 0x18, 0x10, 0x01, 0, 0, 0, 0],
                vec![0x20, 0, 0, 0, 0, 0, 0, 0],
                vec![0x31, 0, 0, 0, 0, 0, 0, 0],
            ],
        ),
    );
    put(
        "sdo_client",
        "segmented_upload",
        &records(
            &[0, 0],
            &[
                vec![0x41, 0x64, 0x60, 0x00, 10, 0, 0, 0],
                vec![0x00, 1, 2, 3, 4, 5, 6, 7],
                vec![0x19, 8, 9, 10, 0, 0, 0, 0],
                vec![0x80, 0x7A, 0x60, 0x00, 0x00, 0x00, 0x02, 0x06],
            ],
        ),
    );
    put(
        "sdo_server",
        "transfers",
        &records(
            &[],
            &[
                vec![0x40, 0x64, 0x60, 0x00, 0, 0, 0, 0],
                vec![0x2B, 0x40, 0x60, 0x00, 0x0F, 0x00, 0, 0],
                vec![0x40, 0x08, 0x10, 0x00, 0, 0, 0, 0],
                vec![0x60, 0, 0, 0, 0, 0, 0, 0],
                vec![0x70, 0, 0, 0, 0, 0, 0, 0],
                vec![0x60, 0, 0, 0, 0, 0, 0, 0],
                vec![0x21, 0x08, 0x10, 0x00, 9, 0, 0, 0],
                vec![0x00, b'n', b'e', b'w', b' ', b'n', b'a', b'm'],
                vec![0x1B, b'e', b'!', 0, 0, 0, 0, 0],
                vec![0x23, 0x18, 0x10, 0x01, 1, 2, 3, 4],
                vec![0x80, 0x64, 0x60, 0x00, 0, 0, 4, 5],
            ],
        ),
    );
    copy("canopen_eds", "config/canopen/drive.eds", &[5]);
    // Modbus.
    let reqs = [
        Request::ReadHolding {
            address: 0x0100,
            count: 4,
        },
        Request::WriteSingle {
            address: 7,
            value: 0x1234,
        },
        Request::WriteMultiple {
            address: 0x0200,
            values: vec![1, 2, 3, 0xFFFF],
        },
    ];
    let resps = [
        Response::Registers {
            function: 3,
            values: vec![10, 20, 30, 40],
        },
        Response::WroteSingle {
            address: 7,
            value: 0x1234,
        },
        Response::WroteMultiple {
            address: 0x0200,
            count: 4,
        },
    ];
    let mut frames: Vec<Vec<u8>> = Vec::new();
    for pdu in reqs
        .iter()
        .map(Request::encode)
        .chain(resps.iter().map(Response::encode))
    {
        frames.push(rtu_frame(1, &pdu));
        frames.push(Mbap::frame(0x0102, 1, &pdu));
        frames.push(pdu);
    }
    frames.push(vec![0x83, 0x02]);
    frames.push(rtu_frame(2, &[0x90, 0x04]));
    put(
        "modbus_frame",
        "requests_and_responses",
        &records(&[], &frames),
    );
    for f in ["generic.toml", "leadshine-pr0.toml", "oriental-az.toml"] {
        copy("modbus_profile", &format!("config/drives/{f}"), &[]);
    }
    // GigE Vision.
    let commands = [
        Command::Discovery,
        Command::ReadReg(vec![0x0A00, 0x0D04]),
        Command::WriteReg(vec![(0x0A00, 2), (0x0D00, 1500)]),
        Command::ReadMem {
            address: 0x10000,
            count: 512,
        },
        Command::WriteMem {
            address: 0x0200,
            data: b"hello".to_vec(),
        },
        Command::PacketResend {
            channel: 0,
            block_id: 7,
            first: 3,
            last: 5,
        },
    ];
    for (k, c) in commands.into_iter().enumerate() {
        let p = CommandPacket {
            flags: 0x01,
            req_id: k as u16 + 1,
            command: c,
        };
        put("gvcp", &format!("command{k}"), &p.encode());
    }
    let acks = [
        AckBody::ReadReg(vec![2, 1500]),
        AckBody::WriteReg { index: 2 },
        AckBody::ReadMem {
            address: 0x10000,
            data: b"<?xml version=\"1.0\"?>".to_vec(),
        },
        AckBody::WriteMem { index: 5 },
        AckBody::Pending { ms: 200 },
    ];
    for (k, body) in acks.into_iter().enumerate() {
        let a = Ack {
            status: 0,
            ack_id: k as u16 + 1,
            body,
        };
        put("gvcp", &format!("ack{k}"), &a.encode());
    }
    put("gvcp", "ack_error", &Ack::error(0x0080, 0x8006, 9).encode());
    for (name, format, (w, h), size) in [
        ("mono8_8x6", pfnc::MONO8, (8u32, 6u32), 44u32),
        ("mono16_5x4", pfnc::MONO16, (5, 4), 100),
    ] {
        let leader = ImageLeader {
            timestamp: 123_456,
            pixel_format: format,
            width: w,
            height: h,
            offset_x: 0,
            offset_y: 0,
        };
        let data: Vec<u8> = (0..leader.payload_size()).map(|k| (k * 7) as u8).collect();
        let mut packets = Vec::new();
        for id in 0..64 {
            let mut b = Vec::new();
            let more = encode_frame_packet(1, &leader, &data, size, id, &mut b);
            if b.is_empty() {
                break;
            }
            packets.push(b);
            if !more {
                break;
            }
        }
        // Header: width-1, height-1, format index, packet size index.
        let fmt = if format == pfnc::MONO8 { 0 } else { 1 };
        let size_index = [37, 44, 100, 200, 291, 1500]
            .iter()
            .position(|&s| s == size)
            .unwrap();
        put(
            "gvsp",
            name,
            &records(
                &[(w - 1) as u8, (h - 1) as u8, fmt, size_index as u8],
                &packets,
            ),
        );
    }
    copy("genicam_xml", "config/gige/sim-camera.xml", &[]);
    let xml = std::fs::read(fuzz_dir().join("../../config/gige/sim-camera.xml")).unwrap();
    put(
        "gige_zip",
        "deflated",
        &zip::store_one("cam.xml", &xml[..1024], true),
    );
    put(
        "gige_zip",
        "stored",
        &zip::store_one("a.xml", b"<a/>", false),
    );
    put(
        "gige_url",
        "url",
        b"Local:sim-camera.xml;10000;3a1f\0\0\0\0",
    );
    put("gige_url", "url_0x", b"local:cam.zip;0x8000;0X200");
    // Frames.
    let tmp = std::env::temp_dir().join("fuzz-seed.png");
    let grey8 = MonoImage::new(
        12,
        9,
        Pixels::Mono8((0..108).map(|k| (k * 2) as u8).collect()),
    )
    .unwrap();
    vision::image_io::save_png(&grey8, &tmp).unwrap();
    put("png_load", "mono8.png", &std::fs::read(&tmp).unwrap());
    let grey16 = MonoImage::new(7, 5, Pixels::Mono16((0..35).map(|k| k * 1800).collect())).unwrap();
    vision::image_io::save_png(&grey16, &tmp).unwrap();
    put("png_load", "mono16.png", &std::fs::read(&tmp).unwrap());
    let _ = std::fs::remove_file(&tmp);
    // Dark dots of 5 px every 10 px (a 0.5 mm board at 50 um/px) on 48 x 48 pixels.
    let (w, h) = (48usize, 48usize);
    let mut px = vec![220u8; w * h];
    for y in 0..h {
        for x in 0..w {
            let (dx, dy) = ((x % 10) as f64 - 4.5, (y % 10) as f64 - 4.5);
            if dx * dx + dy * dy <= 6.25 {
                px[y * w + x] = 30;
            }
        }
    }
    put(
        "localize",
        "dots_50um",
        &[&[(w - 8) as u8, (h - 8) as u8, 0, 1][..], &px].concat(),
    );
    // TOML files.
    for f in [
        "demo",
        "grbl-demo",
        "modbus-demo",
        "canopen-demo",
        "gige-demo",
    ] {
        copy("job_toml", &format!("config/gateway/{f}.toml"), &[]);
    }
    copy("board_toml", "config/boards/dot-grid-0.5mm.toml", &[]);
    put(
        "board_toml",
        "certificate.csv",
        b"i,j,x_mm,y_mm\n0,0,-0.000075,0.000562\n1,0,0.499854,0.000566\n5,4,2.500100,1.999900\n",
    );
    copy("machine_toml", "config/machines/c5-stage.toml", &[]);
    for f in ["mono-1.3mp", "mono-5mp"] {
        copy("camera_toml", &format!("config/cameras/{f}.toml"), &[]);
    }
}
