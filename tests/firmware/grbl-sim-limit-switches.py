"""Limit switches for grbl-sim (the simulator harness, never GRBL's own logic).

Applied by tests/firmware/build.sh to the tree ../shared/peers/build-grbl-sim.sh built,
before `make main` again. Upstream grbl-sim leaves every input pin at 0 (its
grbl_per_tick says "TODO: set limit pins based on position"), so with GRBL's pull-ups
and `$5=0` every limit reads triggered and `$H` ends in `ALARM:8`. This patch gives each
axis a carriage and a switch:

- the carriage moves one step per step pulse GRBL puts out (a rising edge of the axis's
  step pin, after `$2`), in the direction its direction pin says (after `$3`): the pins,
  not `sys_position`, which GRBL counts on while homing has locked the axis's pulses;
- the switch is a normally open contact to ground on GRBL's input pull-up (GRBL's
  default wiring, `$5=0`): its pin reads 1 until the carriage reaches the switch,
  0 from there on. A switch at +N steps is pressed at positions >= N (the side GRBL
  homes toward with `$23=0`), one at -N at positions <= -N, and 0 means no switch.
- `grbl_sim.exe -l X,Y,Z` (steps from the power-up position; one number for every axis)
  places them; the default is +1250 on every axis (5 mm at GRBL's default 250 step/mm).
- EEPROM writes reach the file at once (fflush), as an AVR's EEPROM write is durable:
  a setting stored just before the simulator is killed is there at the next power-up.

Hard limits (`$21=1`) are not modelled: the simulator raises no pin-change interrupt.
Usage: python3 grbl-sim-limit-switches.py GRBL_DIR   (GRBL_DIR holds grbl-sim/)
"""
import sys

d = sys.argv[1]


def patch(path, old, new):
    p = f"{d}/{path}"
    s = open(p).read()
    assert s.count(old) == 1, f"{path}: {old!r}"
    open(p, "w").write(s.replace(old, new))


patch("grbl-sim/grbl_interface.c", """void grbl_per_tick(void){
  //maybe print the position every tick
  print_steps(0);
""", """// limitsw: each axis's carriage (steps from power-up, counted from the step and
// direction pins) and its switch (steps; > 0 pressed at or past it, < 0 at or below
// it, 0 none). Set by `-l` (main.c).
#include <stdlib.h>
long sim_limit_switch_steps[N_AXIS] = {1250, 1250, 1250};
static long sim_carriage_steps[N_AXIS];

// `X,Y,Z` or one value for every axis; 0 when parsed, -1 otherwise.
int sim_parse_limit_switches(const char *text) {
  long v[N_AXIS];
  int n = 0;
  const char *s = text;
  char *end;
  for (;;) {
    if (n == N_AXIS) { return -1; }
    v[n++] = strtol(s, &end, 10);
    if (end == s) { return -1; }
    if (*end == 0) { break; }
    if (*end != ',') { return -1; }
    s = end + 1;
  }
  if (n != 1 && n != N_AXIS) { return -1; }
  int i;
  for (i = 0; i < N_AXIS; i++) { sim_limit_switch_steps[i] = v[n == 1 ? 0 : i]; }
  return 0;
}

static void sim_limit_switches(void) {
  static uint8_t step_was_active = 0, port_was = 0, started = 0;
  uint8_t step_invert = 0, pins = 0, idx;
  // Every tick: only a change of the step pins can move a carriage.
  uint8_t port = STEP_PORT & STEP_MASK;
  if (started && port == port_was) { return; }
  started = 1;
  port_was = port;
  for (idx = 0; idx < N_AXIS; idx++) {
    if (settings.step_invert_mask & bit(idx)) { step_invert |= get_step_pin_mask(idx); }
  }
  uint8_t active = (STEP_PORT ^ step_invert) & STEP_MASK;
  uint8_t rising = active & ~step_was_active;
  step_was_active = active;
  for (idx = 0; idx < N_AXIS; idx++) {
    if (rising & get_step_pin_mask(idx)) {
      uint8_t dir_pin = (DIRECTION_PORT & get_direction_pin_mask(idx)) != 0;
      uint8_t dir_inverted = (settings.dir_invert_mask & bit(idx)) != 0;
      sim_carriage_steps[idx] += (dir_pin != dir_inverted) ? -1 : 1;
    }
    long at = sim_limit_switch_steps[idx], pos = sim_carriage_steps[idx];
    uint8_t pressed = (at > 0 && pos >= at) || (at < 0 && pos <= at);
    if (!pressed) { pins |= get_limit_pin_mask(idx); } // pull-up: open reads 1
  }
  LIMIT_PIN = (LIMIT_PIN & ~LIMIT_MASK) | pins;
}

void grbl_per_tick(void){
  sim_limit_switches(); // limitsw
  //maybe print the position every tick
  print_steps(0);
""")

# The pins read right before GRBL's first instruction, not only after the first tick.
patch("grbl-sim/grbl_interface.c", """  //setup local tacking vars
  next_print_time = args.step_time;
""", """  //setup local tacking vars
  next_print_time = args.step_time;
  sim_limit_switches(); // limitsw
""")
patch("grbl-sim/grbl_interface.c", "void print_steps(bool force);\n",
      "void print_steps(bool force);\nstatic void sim_limit_switches(void); // limitsw\n")

patch("grbl-sim/main.c", """     case 'h':
      return usage(NULL);""", """     case 'l': //limitsw: limit switch positions
      argv++;argc--;
      if (argc < 1 || sim_parse_limit_switches(*argv)) {
        printf("-l wants X,Y,Z (or one value): limit switch steps from power-up, got %s\\n",
               argc < 1 ? "nothing" : *argv);
        return(usage(0));
      }
      break;
     case 'h':
      return usage(NULL);""")
patch("grbl-sim/main.c", """      "    -n                 : no comments before grbl response lines.\\n\"""",
      """      "    -n                 : no comments before grbl response lines.\\n"
      "    -l <X,Y,Z>         : limit switch of each axis, steps from power-up (one\\n"
      "                         value: every axis); >0 pressed at or past it, <0 at or\\n"
      "                         below it, 0 none. Default=1250,1250,1250.\\n\"""")
patch("grbl-sim/main.c", "int avr_main(void);\n",
      "int avr_main(void);\nint sim_parse_limit_switches(const char *text); // limitsw\n")

patch("grbl-sim/avr/eeprom.c", "  fputc(new_value, fp);\n",
      "  fputc(new_value, fp);\n  fflush(fp); // limitsw: durable at once, as an AVR's EEPROM write\n")
