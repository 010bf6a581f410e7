//! The controllers' own compensation tables (Siemens EEC/CEC, Fanuc pitch error,
//! Heidenhain `.COM`/`.CMA` and 64-value, Haas lead screw), each written by
//! `errormap::export` and read back by an independent reader written from the manuals'
//! description (`controller_tables_reader`), which evaluates the correction the control
//! applies at random points approached from random sides and compares it with the map.
//! The residual per format on the demo stage's map is printed for docs/error-map.md
//! (`cargo test -p system-tests --test system controller_tables:: -- --nocapture`).

use crate::controller_tables_reader;

use controller_tables_reader as reader;
use errormap::export::{
    fanuc_pitch, haas, heidenhain_64, heidenhain_com, siemens, CecMultiplier, ControllerTables,
    FanucOptions, FanucSection, SiemensOptions, ValueSign,
};
use errormap::{Approach, Direction, MapModel};
use job::{Job, StageSpec};
use protocol::errormap::Identity;
use system_tests::truth_map::map_from_truth;

/// The demo job's stage, thermal drift off, as a perfect scan maps it.
fn demo_map() -> MapModel {
    let mut job = Job::demo();
    let StageSpec::Sim { machine } = &mut job.stage else {
        unreachable!("the demo job simulates its stage")
    };
    machine.thermal = None;
    let identity = Identity {
        machine: "sim".into(),
        controller: "sim".into(),
        board: job.board.name.clone(),
        certificate_sha256: job.board.fingerprint_sha256(),
        camera: "sim".into(),
    };
    MapModel::new(map_from_truth(machine, identity))
}

/// A small deterministic generator (xorshift64*).
struct Rng(u64);
impl Rng {
    fn unit(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// What the reader's correction leaves of the map: max and rms over `n` random points,
/// each axis approached from a random side, um. `zero_um` is the constant the control's
/// zero cannot hold (stated by the writer, set by the reference).
fn residual(
    model: &MapModel,
    zero_um: [f64; 2],
    n: usize,
    applied_mm: &dyn Fn([f64; 2], [reader::Side; 2]) -> [f64; 2],
) -> (f64, f64) {
    let (lo, hi) = model.extent();
    let mut rng = Rng(0x5eed_1234_abcd_ef01);
    let (mut max, mut sum2) = (0.0f64, 0.0);
    for _ in 0..n {
        let p = [
            lo[0] + (hi[0] - lo[0]) * rng.unit(),
            lo[1] + (hi[1] - lo[1]) * rng.unit(),
        ];
        let sides: [reader::Side; 2] = [
            if rng.unit() < 0.5 { 1 } else { -1 },
            if rng.unit() < 0.5 { 1 } else { -1 },
        ];
        let a = |s: reader::Side| {
            if s > 0 {
                Approach::Forward
            } else {
                Approach::Reverse
            }
        };
        let dir = Direction {
            x: a(sides[0]),
            y: a(sides[1]),
        };
        let e = model.tool_error_um(p, dir).expect("inside the map");
        let c = applied_mm(p, sides);
        for k in 0..2 {
            let r = e[k] - zero_um[k] - c[k] * 1000.0;
            max = max.max(r.abs());
            sum2 += r * r;
        }
    }
    (max, (sum2 / (2 * n) as f64).sqrt())
}

fn file<'a>(t: &'a ControllerTables, suffix: &str) -> &'a str {
    &t.files
        .iter()
        .find(|(s, _)| s == suffix)
        .unwrap_or_else(|| panic!("no `{suffix}` file"))
        .1
}

const POINTS: usize = 4000;

/// Each format's residual from its independent reader; the writer's own estimate must
/// agree with it (two evaluations of the same tables, one from the file).
fn check(name: &str, t: &ControllerTables, reader_fit: (f64, f64)) -> (f64, f64) {
    let (max, rms) = reader_fit;
    println!(
        "{name:<34} reader: max {max:6.2} rms {rms:5.2} um | writer: max {:6.2} rms {:5.2} um, share {:.4}, worst at ({:.1}, {:.1}) mm, zero not held ({:.2}, {:.2}) um | map max {:.2} rms {:.2} um",
        t.fit.max_um, t.fit.rms_um, t.fit.share, t.fit.worst_at_mm[0], t.fit.worst_at_mm[1], t.zero_not_held_um[0], t.zero_not_held_um[1], t.fit.map_max_um, t.fit.map_rms_um
    );
    assert!(
        (rms - t.fit.rms_um).abs() < 0.1 * t.fit.rms_um.max(1.0),
        "{name}: the reader's rms {rms:.3} um and the writer's {:.3} um disagree",
        t.fit.rms_um
    );
    assert!(
        max <= t.fit.max_um * 1.1 + 0.2,
        "{name}: the reader finds {max:.3} um, beyond the writer's {:.3} um",
        t.fit.max_um
    );
    (max, rms)
}

#[test]
fn every_format_read_back_independently_on_the_demo_map() {
    let model = demo_map();
    let map_fit = {
        let none = |_: [f64; 2], _: [reader::Side; 2]| [0.0, 0.0];
        residual(&model, [0.0; 2], POINTS, &none)
    };
    println!(
        "demo map, {POINTS} random points, random sides: max {:.2} rms {:.2} um uncompensated",
        map_fit.0, map_fit.1
    );

    // Siemens EEC alone, then EEC + CEC (828D: 8 tables of 200 points).
    let opts = SiemensOptions::default();
    let eec_only = siemens(&model, &opts, false).expect("EEC writes");
    let read_eec = |t: &ControllerTables| -> [reader::Eec; 2] {
        ["x", "y"].map(|s| {
            let ini = reader::SiemensIni::parse(file(t, s)).expect("the EEC file parses");
            let axis = if s == "x" { "X1" } else { "Y1" };
            reader::Eec::read(&ini, axis, 200).expect("the EEC table is consistent")
        })
    };
    let eec = read_eec(&eec_only);
    let eec_fit = check(
        "siemens-eec",
        &eec_only,
        residual(&model, [0.0; 2], POINTS, &|p, _| {
            [eec[0].at(p[0]), eec[1].at(p[1])]
        }),
    );

    let set = siemens(&model, &opts, true).expect("EEC + CEC writes");
    let eec = read_eec(&set);
    let ini = reader::SiemensIni::parse(file(&set, "cec")).expect("the CEC file parses");
    let cec = reader::Cec::read(&ini, 200, 8, false).expect("the CEC tables are consistent");
    assert_eq!(cec.count(), 6, "2 cross tables and 4 direction tables");
    let names = ["X1", "Y1"];
    let cec_fit = check(
        "siemens-cec (EEC + 6 CEC)",
        &set,
        residual(&model, [0.0; 2], POINTS, &|p, sides| {
            let pos = |a: &str| p[names.iter().position(|n| *n == a).expect("X1 or Y1")];
            let side = |a: &str| sides[names.iter().position(|n| *n == a).expect("X1 or Y1")];
            [
                eec[0].at(p[0]) + cec.at("X1", &pos, &side),
                eec[1].at(p[1]) + cec.at("Y1", &pos, &side),
            ]
        }),
    );
    // The cross-axis error (squareness, straightness) a per-axis table cannot hold.
    assert!(
        cec_fit.1 < 0.5 * eec_fit.1,
        "EEC + CEC rms {:.2} um is not well below EEC alone {:.2} um",
        cec_fit.1,
        eec_fit.1
    );

    // With products in the remaining two tables, the multiplier's own output added.
    for mode in [
        CecMultiplier::OwnOutputAdded,
        CecMultiplier::OwnOutputNotAdded,
    ] {
        let o = SiemensOptions {
            multiplier: mode,
            ..SiemensOptions::default()
        };
        let set = siemens(&model, &o, true).expect("EEC + CEC with products writes");
        let eec = read_eec(&set);
        let ini = reader::SiemensIni::parse(file(&set, "cec")).expect("the CEC file parses");
        let added = mode == CecMultiplier::OwnOutputAdded;
        let cec = reader::Cec::read(&ini, 200, 8, added).expect("consistent");
        assert_eq!(cec.count(), 8);
        check(
            &format!("siemens-cec products ({})", mode.as_str()),
            &set,
            residual(&model, [0.0; 2], POINTS, &|p, sides| {
                let pos = |a: &str| p[names.iter().position(|n| *n == a).expect("X1 or Y1")];
                let side = |a: &str| sides[names.iter().position(|n| *n == a).expect("X1 or Y1")];
                [
                    eec[0].at(p[0]) + cec.at("X1", &pos, &side),
                    eec[1].at(p[1]) + cec.at("Y1", &pos, &side),
                ]
            }),
        );
    }

    // Fanuc, each section reading.
    for (section, shape) in [
        (FanucSection::StepEnding, reader::FanucShape::StepEnding),
        (FanucSection::StepStarting, reader::FanucShape::StepStarting),
        (FanucSection::Ramp, reader::FanucShape::Ramp),
    ] {
        let o = FanucOptions {
            section,
            ..FanucOptions::default()
        };
        let t = fanuc_pitch(&model, &o).expect("the Fanuc file writes");
        let f = reader::FanucPitch::parse(file(&t, ""), true, 0.001, false, 10000)
            .expect("the Fanuc file parses");
        check(
            &format!("fanuc-pitch ({})", section.as_str()),
            &t,
            residual(&model, t.zero_not_held_um, POINTS, &|p, _| {
                [f.at(0, p[0], &shape), f.at(1, p[1], &shape)]
            }),
        );
    }

    // Heidenhain .COM/.CMA.
    let t = heidenhain_com(&model, "demo", 256, ValueSign::Correction).expect("writes");
    let com = |name: &str| match name {
        "DEMO_X.COM" | "DEMO_Y.COM" => Some(file(&t, name).to_string()),
        _ => None,
    };
    let h =
        reader::HeidenhainCom::read(file(&t, "DEMO.CMA"), &com, false).expect("the tables read");
    let axes = ["X", "Y"];
    check(
        "heidenhain (.COM/.CMA)",
        &t,
        residual(&model, [0.0; 2], POINTS, &|p, sides| {
            let pos = |a: &str| p[axes.iter().position(|n| *n == a).expect("X or Y")];
            let side = |a: &str| sides[axes.iter().position(|n| *n == a).expect("X or Y")];
            [h.at("X", &pos, &side), h.at("Y", &pos, &side)]
        }),
    );

    // Heidenhain TNC 306/360.
    let t = heidenhain_64(&model, ValueSign::Correction).expect("writes");
    let hx = reader::Heidenhain64::parse(file(&t, "x"), false).expect("X reads");
    let hy = reader::Heidenhain64::parse(file(&t, "y"), false).expect("Y reads");
    assert_eq!((hx.axis.as_str(), hy.axis.as_str()), ("X", "Y"));
    check(
        "heidenhain-64 (TNC 306/360)",
        &t,
        residual(&model, t.zero_not_held_um, POINTS, &|p, _| {
            [hx.at(p[0]), hy.at(p[1])]
        }),
    );

    // Haas: machine zero at the map's upper end.
    let t = haas(&model, ValueSign::Correction, None).expect("writes");
    let ax = reader::HaasLeadScrew::parse(file(&t, "x"), false).expect("X reads");
    let ay = reader::HaasLeadScrew::parse(file(&t, "y"), false).expect("Y reads");
    let (_, hi) = model.extent();
    check(
        "haas",
        &t,
        residual(&model, [0.0; 2], POINTS, &|p, _| {
            [
                ax.at((p[0] - hi[0]) / 25.4) * 25.4,
                ay.at((p[1] - hi[1]) / 25.4) * 25.4,
            ]
        }),
    );
}

fn close(got: f64, want: f64, what: &str) {
    assert!(
        (got - want).abs() < 1e-9,
        "{what}: got {got}, expected {want}"
    );
}

/// The readers on the five-point examples of docs/error-map.md (the notes' examples,
/// completed to five points), at three positions each: what the control applies (the
/// correction added to the command, mm).
#[test]
fn five_point_examples_as_the_control_applies_them() {
    // Siemens EEC: the error; the control moves by minus it.
    let eec = "%_N_X1_EEC_INI\nCHANDATA(1)\n$AA_ENC_COMP[0,0,X1]=0.0\n$AA_ENC_COMP[0,1,X1]=0.004\n$AA_ENC_COMP[0,2,X1]=0.006\n$AA_ENC_COMP[0,3,X1]=0.002\n$AA_ENC_COMP[0,4,X1]=0.0\n$AA_ENC_COMP_STEP[0,X1]=100.0\n$AA_ENC_COMP_MIN[0,X1]=0.0\n$AA_ENC_COMP_MAX[0,X1]=400.0\n$AA_ENC_COMP_IS_MODULO[0,X1]=0\nM17\n";
    let ini = reader::SiemensIni::parse(eec).expect("parses");
    let t = reader::Eec::read(&ini, "X1", 5).expect("5 points fit MD38000 = 5");
    close(-t.at(150.0), -0.005, "EEC at 150");
    close(-t.at(320.0), -0.0016, "EEC at 320");
    close(-t.at(450.0), 0.0, "EEC at 450 (last value held)");
    let e = reader::Eec::read(&ini, "X1", 4)
        .err()
        .expect("MD38000 = 4 refuses 5 points");
    assert!(e.contains("the machine data allows 4"), "{e}");

    // Siemens CEC: Y1 -> Z1, both directions.
    let cec = |direction: i8| {
        format!("%_N_NC_CEC_INI\nCHANDATA(1)\n$AN_CEC[0,0]=0\n$AN_CEC[0,1]=-0.004\n$AN_CEC[0,2]=-0.010\n$AN_CEC[0,3]=-0.004\n$AN_CEC[0,4]=0\n$AN_CEC_INPUT_AXIS[0]=(Y1)\n$AN_CEC_OUTPUT_AXIS[0]=(Z1)\n$AN_CEC_STEP[0]=100\n$AN_CEC_MIN[0]=-200\n$AN_CEC_MAX[0]=200\n$AN_CEC_DIRECTION[0]={direction}\n$AN_CEC_MULT_BY_TABLE[0]=0\n$AN_CEC_IS_MODULO[0]=0\nM17\n")
    };
    let c = reader::Cec::read(
        &reader::SiemensIni::parse(&cec(0)).expect("parses"),
        5,
        8,
        false,
    )
    .expect("consistent");
    let z = |y: f64, side: reader::Side| -c.at("Z1", &|_| y, &|_| side);
    close(z(50.0, 1), 0.007, "CEC at Y 50");
    close(z(-150.0, -1), 0.002, "CEC at Y -150");
    close(z(250.0, 1), 0.0, "CEC at Y 250 (held)");
    let c = reader::Cec::read(
        &reader::SiemensIni::parse(&cec(1)).expect("parses"),
        5,
        8,
        false,
    )
    .expect("consistent");
    close(
        c.at("Z1", &|_| 50.0, &|_| -1),
        0.0,
        "a + only table moving in -",
    );
    // The 802D sl example: 350 points at 6.73 mm over -400..400 cannot be.
    let mut t802 = String::from("%_N_NC_CEC_INI\nCHANDATA(1)\n");
    for i in 0..350 {
        t802.push_str(&format!("$AN_CEC[0,{i}]=0\n"));
    }
    t802.push_str("$AN_CEC_INPUT_AXIS[0]=(X1)\n$AN_CEC_OUTPUT_AXIS[0]=(Z1)\n$AN_CEC_STEP[0]=6.73\n$AN_CEC_MIN[0]=-400\n$AN_CEC_MAX[0]=400\n$AN_CEC_DIRECTION[0]=0\n$AN_CEC_MULT_BY_TABLE[0]=0\n$AN_CEC_IS_MODULO[0]=0\nM17\n");
    let e = reader::Cec::read(
        &reader::SiemensIni::parse(&t802).expect("parses"),
        1000,
        8,
        false,
    )
    .err()
    .expect("the 802D example is refused");
    assert!(e.contains("119.871 points, 350 written"), "{e}");

    // Fanuc: 3620 = 40, 50 mm in 1 um units, points 41..44 = +2 +1 -1 0 (corrections).
    let fanuc = "%\nN03620A1P40 \nN03621A1P40 \nN03622A1P44 \nN03623A1P1\nN03624A1P50000\nN10040P0\nN10041P2\nN10042P1\nN10043P-1 \nN10044P0\n%\n";
    let f = reader::FanucPitch::parse(fanuc, true, 0.001, false, 10000).expect("parses");
    let at = |s: f64, shape| -f.at(0, s, &shape);
    close(
        at(20.0, reader::FanucShape::StepEnding),
        0.002,
        "Fanuc at 20",
    );
    close(
        at(75.0, reader::FanucShape::StepEnding),
        0.003,
        "Fanuc at 75",
    );
    close(
        at(180.0, reader::FanucShape::StepEnding),
        0.002,
        "Fanuc at 180",
    );
    close(
        at(75.0, reader::FanucShape::StepStarting),
        0.002,
        "Fanuc at 75, section starting",
    );
    close(
        at(75.0, reader::FanucShape::Ramp),
        0.0025,
        "Fanuc at 75, ramp",
    );
    let odd = fanuc.replace("N03620A1P40 \n", "N03620A1P40\n");
    let e = reader::FanucPitch::parse(&odd, true, 0.001, false, 10000)
        .err()
        .expect("TV check");
    assert!(e.contains("TV check"), "{e}");

    // Heidenhain .COM/.CMA: X = F(X) with BACKLASH, values as corrections.
    let cma = "BEGIN EX.CMA\nNR    X             ACTIVE\n0     EX_X.COM      *\n[END]\n";
    let com = "BEGIN EX_X.COM MM\nNR    AXISPOS   X         BACKLASH\n0     +0.0000   +0.0000   +0.0020\n1     +50.0000  -0.0020   +0.0020\n2     +100.0000 -0.0030   +0.0020\n3     +150.0000 -0.0010   +0.0020\n4     +200.0000 +0.0000   +0.0020\n[END]\n";
    let h =
        reader::HeidenhainCom::read(cma, &|n| (n == "EX_X.COM").then(|| com.to_string()), false)
            .expect("reads");
    let x = |s: f64, side: reader::Side| -h.at("X", &|_| s, &|_| side);
    close(x(25.0, 1), -0.001, "Heidenhain at 25");
    close(x(120.0, 1), -0.0022, "Heidenhain at 120");
    close(x(120.0, -1), -0.0002, "Heidenhain at 120 moving in -");

    // Heidenhain TNC 306/360: SETUP 14 = 16.384 mm spacing.
    let old = "X=F(X)\nDATUM POINT X+0.000\nSETUP 14\n0 X+0.000 X+0.0000\n1 X+16.384 X-0.0040\n2 X+32.768 X-0.0060\n3 X+49.152 X-0.0050\n4 X+65.536 X-0.0010\n";
    let o = reader::Heidenhain64::parse(old, false).expect("reads");
    close(-o.at(8.192), -0.002, "TNC 306 at 8.192");
    close(-o.at(40.96), -0.0055, "TNC 306 at 40.96");
    close(-o.at(100.0), -0.001, "TNC 306 at 100 (held)");
    let e = reader::Heidenhain64::parse(&old.replace("X-0.0040", "X-0.3000"), false)
        .err()
        .expect("more than spacing / 64 between values");
    assert!(e.contains("spacing / 64"), "{e}");

    // Haas: every 0.5 in down from machine zero, inches.
    let haas = "HAAS\nENTRY  MACHINE_IN  VALUE_IN\n0      0.0000      +0.0000\n1      -0.5000     +0.0002\n2      -1.0000     +0.0003\n3      -1.5000     +0.0001\n4      -2.0000     +0.0000\n";
    let a = reader::HaasLeadScrew::parse(haas, false).expect("reads");
    close(-a.at(-0.25), 0.0001, "Haas at -0.25 in");
    close(-a.at(-1.25), 0.0002, "Haas at -1.25 in");
    close(-a.at(-1.75), 0.00005, "Haas at -1.75 in");
}

/// What the writers refuse, naming the limit.
#[test]
fn the_writers_refuse_what_the_control_refuses() {
    let model = demo_map();
    let e = siemens(
        &model,
        &SiemensOptions {
            axes: ["x1".into(), "Y1".into()],
            ..SiemensOptions::default()
        },
        false,
    )
    .expect_err("a lower-case axis name");
    assert!(e.to_string().contains("Siemens axis name \"x1\""), "{e}");
    let e = fanuc_pitch(
        &model,
        &FanucOptions {
            max_increment: 2,
            ..FanucOptions::default()
        },
    )
    .expect_err("the demo's pitch error needs more than 2 units a point");
    assert!(e.to_string().contains("past the 2 a point holds"), "{e}");
    let e = siemens(
        &model,
        &SiemensOptions {
            points: 5000,
            multiplier: CecMultiplier::OwnOutputAdded,
            ..SiemensOptions::default()
        },
        true,
    )
    .expect_err("products over 5000 x 5000 points");
    assert!(e.to_string().contains("at most 4000000"), "{e}");
    let e = heidenhain_com(&model, "demo", 300, ValueSign::Correction).expect_err("300 entries");
    assert!(e.to_string().contains("a table holds 2 to 256"), "{e}");
    let e = haas(&model, ValueSign::Correction, Some([1e6, 1e6]))
        .expect_err("127 steps at 10^6 per inch is 0.000127 in");
    assert!(
        e.to_string().contains("past the +-127 encoder steps"),
        "{e}"
    );
}
