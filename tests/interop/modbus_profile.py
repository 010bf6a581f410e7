"""A drive profile (config/drives/*.toml) read independently of the Rust code: register
addresses, types and word order, and the move block encoded as the profile says."""

import tomllib

WORDS = {"u16": 1, "i16": 1, "u32": 2, "i32": 2}


class Reg:
    def __init__(self, key, raw, order, default_type="u16"):
        self.key = key
        self.address = raw["address"]
        self.type = raw.get("type", default_type)
        self.table = raw.get("table", "holding")
        self.order = raw.get("word_order", order)
        self.words = WORDS[self.type]

    def encode(self, value):
        if self.words == 1:
            return [value & 0xFFFF]
        v = value & 0xFFFFFFFF
        hi, lo = v >> 16, v & 0xFFFF
        return [hi, lo] if self.order == "high-first" else [lo, hi]

    def decode(self, words):
        if self.words == 1:
            v = words[0]
            return v - 0x10000 if self.type == "i16" and v >= 0x8000 else v
        hi, lo = (words[0], words[1]) if self.order == "high-first" else (words[1], words[0])
        v = (hi << 16) | lo
        return v - 0x100000000 if self.type == "i32" and v >= 0x80000000 else v


class Profile:
    def __init__(self, path):
        with open(path, "rb") as f:
            d = tomllib.load(f)
        drive = d["drive"]
        order = drive.get("word_order", "high-first")
        self.counts_per_mm = drive["counts_per_rev"] / drive["mm_per_rev"]
        self.mm_per_rev = drive["mm_per_rev"]
        self.accel = drive["accel_mm_s2"]
        self.decel = drive.get("decel_mm_s2", self.accel)
        m = d["move"]
        self.position = Reg("move.position", m["position"], order)
        self.trigger = Reg("move.trigger", m["trigger"], order)
        self.trigger_value = m["trigger"]["value"]
        self.scaled = {k: (Reg("move." + k, m[k], order), m[k]["unit"]) for k in ("speed", "accel", "decel") if k in m}
        self.fixed = [(Reg("move.fixed", f, order), f["value"]) for f in m.get("fixed", [])]
        block = [self.position, self.trigger] + [r for r, _ in self.scaled.values()] + [r for r, _ in self.fixed]
        self.block_start = min(r.address for r in block)
        self.block_len = max(r.address + r.words for r in block) - self.block_start
        self.block = block
        self.actual = Reg("position", d["position"], order)
        s = d["status"]
        self.status = Reg("status.register", s["register"], order)
        self.bits = {k: s.get(k) for k in ("ready", "busy", "in_position", "alarm", "home_done")}
        c = d["commands"]
        self.commands = {k: (Reg("commands." + k, c[k], order), c[k]["value"], c[k].get("release")) for k in c}
        a = d.get("alarm", {})
        self.alarm_code = Reg("alarm.code", a["code"], order) if "code" in a else None

    def to_register(self, unit, physical):
        cpm = self.counts_per_mm
        if unit in ("counts", "counts/s", "counts/s2"):
            return physical * cpm
        if unit == "rpm":
            return physical * 60.0 / self.mm_per_rev
        if unit == "ms/1000rpm":
            return 1e6 / (physical * 60.0 / self.mm_per_rev)
        raise ValueError(unit)

    def move_words(self, position_mm, speed_mm_s):
        words = [0] * self.block_len

        def put(reg, value):
            at = reg.address - self.block_start
            words[at:at + reg.words] = reg.encode(int(round(value)))

        put(self.position, position_mm * self.counts_per_mm)
        phys = {"speed": speed_mm_s, "accel": self.accel, "decel": self.decel}
        for k, (reg, unit) in self.scaled.items():
            put(reg, self.to_register(unit, phys[k]))
        for reg, value in self.fixed:
            put(reg, value)
        put(self.trigger, self.trigger_value)
        return words
