// The eskin board under emulation: simavr runs the compiled firmware, its UART on a
// pseudo-terminal (simavr's uart_pty part), and this harness plays the rig around it.
//
//   eskin_emulator <firmware.elf> <link>
//
// <link> is a symlink that follows the firmware's pty, as udev's /dev/serial/by-id/ names
// follow a board that is unplugged and plugged back.
// It is built for one skin size, against the firmware's board.h and generated skin.h (the
// Makefile: build/<R>x<C>/), and watches the pins board.h names: the multiplexers' select
// and enable lines (which terminal reaches the CAV424, by skin.h's TERMINAL_MAP) and the
// stepper's STEP and DIR (where the clamp is). Each ADC
// conversion is answered with the voltage of the selected terminal. The voltages come
// from the skin model, which lives in the Python process that started this one, over
// stdin/stdout, one line each way:
//
//   → PTY <link>                the firmware's serial port, once, at start
//   → FRAME <steps>             a scan begins (x1 selected); the clamp's position in steps
//   ← VOLTS <v1> ... <vN>       that scan's TERMINALS voltages, in units of 5 V / 65535
//   ← RESET                     (instead of VOLTS) reset the board
//   ← VANISH <ms>               (instead of VOLTS) the USB link drops: the pty closes (the
//                               host's open port hangs up) and <link> is gone; <ms> later
//                               it comes back on a new pty that <link> points to, and the
//                               board resets, as an Uno does when its port is opened (DTR).
//                               The board keeps its own supply (the stepper needs one), so
//                               the clamp's position survives in .noinit (board.h).
//
// The harness waits for the answer before the emulation goes on, so emulated time does
// not depend on the Python side's speed. Diagnostics go to stderr.
#include <errno.h>
#include <pty.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <unistd.h>

#include <simavr/avr_adc.h>
#include <simavr/avr_ioport.h>
#include <simavr/parts/uart_pty.h>
#include <simavr/sim_avr.h>
#include <simavr/sim_elf.h>

#include "board.h"

// An Arduino Uno pin number's port and bit: D0..D7 are PD0..PD7, D8..D13 PB0..PB5.
#define PORT_OF(pin) ((pin) < 8 ? 'D' : 'B')
#define BIT_OF(pin) ((pin) < 8 ? (pin) : (pin) - 8)
#define MULTIPLEXERS 4  // board.h's MUX_ENABLE_PINS
#define CHANNELS 16     // a 74HC4067's
// Units of the voltages simavr's ADC is given: it keeps them in 16 bits, so 5 V (the
// supply, AVcc) is 65535 units of 76.3 µV.
#define SUPPLY 65535
#define TEXT_(value) #value
#define TEXT(value) TEXT_(value)

static avr_t *avr;
static FILE *python;           // the protocol's output (stdout before it was redirected)
static const int mux_enable[MULTIPLEXERS] = MUX_ENABLE_PINS;
static const int select_pins[4] = {PIN_MUX_S0, PIN_MUX_S1, PIN_MUX_S2, PIN_MUX_S3};
static int terminal_at[MULTIPLEXERS][CHANNELS];  // by skin.h's TERMINAL_MAP; -1: none
static uint32_t volts[TERMINALS];
static int terminal = -1;      // the terminal that reaches the CAV424, -1 for none
static int select_bits = 0, enabled[MULTIPLEXERS] = {0}, extending = 0;
static long position_steps = 0;
static int reset_asked = 0;
static long vanish_ms = -1;    // VANISH asked: the milliseconds the link stays away
static uart_pty_t pty;
static const char *link_path;
static int kept_slave = -1;    // the current pty's slave, held open after a VANISH
static int frame_due = 0;      // x1 was selected: its conversion starts the next scan

static void fail(const char *what) {
  fprintf(stderr, "eskin_emulator: %s\n", what);
  exit(1);
}

// Ask the skin for the next scan's voltages.
static void next_frame(void) {
  char line[16 + 6 * TERMINALS];
  fprintf(python, "FRAME %ld\n", position_steps);
  fflush(python);
  if (!fgets(line, sizeof line, stdin)) exit(0);  // the Python side is gone: so are we
  if (strncmp(line, "RESET", 5) == 0) {
    reset_asked = 1;
    return;
  }
  if (strncmp(line, "VANISH ", 7) == 0) {
    char *end;
    vanish_ms = strtol(line + 7, &end, 10);
    if (end == line + 7 || vanish_ms < 0) fail("VANISH needs the milliseconds to stay away");
    reset_asked = 1;
    return;
  }
  char *at = line;
  if (strncmp(at, "VOLTS ", 6) != 0) fail("expected VOLTS <" TEXT(TERMINALS) " numbers>");
  at += 6;
  for (int i = 0; i < TERMINALS; i++) {
    char *end;
    unsigned long v = strtoul(at, &end, 10);
    if (end == at || v > SUPPLY)
      fail("VOLTS needs " TEXT(TERMINALS) " numbers in 0..65535 (5 V / 65535)");
    volts[i] = (uint32_t)v;
    at = end;
  }
}

// The terminal the one enabled multiplexer passes on; none when no or several are enabled.
static void update_terminal(void) {
  int now = -1, count = 0;
  for (int mux = 0; mux < MULTIPLEXERS; mux++) {
    if (enabled[mux]) {
      count++;
      now = terminal_at[mux][select_bits];
    }
  }
  if (count != 1) now = -1;
  if (now == 0 && terminal != 0) frame_due = 1;
  terminal = now;
}

static void pin_changed(struct avr_irq_t *irq, uint32_t value, void *param) {
  (void)irq;
  const int pin = (int)(intptr_t)param;
  if (pin == PIN_STEP) {
    if (value) position_steps += extending ? 1 : -1;  // a rising edge is a step
    return;
  }
  if (pin == PIN_DIR) {
    extending = value != 0;
    return;
  }
  for (int i = 0; i < 4; i++) {
    if (pin == select_pins[i]) {
      select_bits = value ? (select_bits | 1 << i) : (select_bits & ~(1 << i));
    }
  }
  for (int mux = 0; mux < MULTIPLEXERS; mux++) {
    if (pin == mux_enable[mux]) enabled[mux] = value == 0;  // enables are active low
  }
  update_terminal();
}

static void watch(int pin) {
  avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(PORT_OF(pin)), BIT_OF(pin)),
                          pin_changed, (void *)(intptr_t)pin);
}

static void conversion(struct avr_irq_t *irq, uint32_t value, void *param) {
  (void)irq; (void)value; (void)param;
  if (frame_due && terminal == 0) {  // a scan reads x1 first
    frame_due = 0;
    next_frame();
  }
  // The CAV424 is on ADC0; simavr takes the value now and converts.
  avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_ADC0),
                terminal >= 0 ? volts[terminal] : 0);
}

// Point <link> at the current pty, atomically (a host opening it never finds it missing).
static void follow_pty(void) {
  char fresh[4096];
  snprintf(fresh, sizeof fresh, "%s.new", link_path);
  unlink(fresh);
  if (symlink(pty.pty.slavename, fresh) != 0 || rename(fresh, link_path) != 0)
    fail("cannot point the link at the pty");
}

// The link drops, and comes back `ms` later. A new pty's master replaces the old one
// under the descriptor uart_pty's thread selects on (dup2 swaps them in one step, so the
// thread never sees a closed descriptor): the old master closes and the host's port hangs
// up. The new pty's slave stays open here, as uart_pty keeps the first one's, so what the
// board says before the host opens the port waits in the pty.
static void vanish(long ms) {
  int master, slave;
  char name[sizeof pty.pty.slavename];
  if (openpty(&master, &slave, name, NULL, NULL) < 0) fail("cannot open a pty");
  struct termios tio;
  tcgetattr(master, &tio);
  cfmakeraw(&tio);
  tcsetattr(master, TCSANOW, &tio);
  unlink(link_path);
  if (dup2(master, pty.pty.s) < 0) fail("cannot replace the pty");
  close(master);
  if (kept_slave >= 0) close(kept_slave);  // the previous VANISH's pty is gone
  kept_slave = slave;
  memcpy(pty.pty.slavename, name, sizeof name);
  usleep((useconds_t)ms * 1000);  // emulated time stands still meanwhile
  follow_pty();
}

int main(int argc, char **argv) {
  if (argc != 3) fail("usage: eskin_emulator <firmware.elf> <link>");
  link_path = argv[2];
  // uart_pty prints its notes on stdout: the protocol keeps the real stdout for itself.
  const int protocol_fd = dup(1);
  if (protocol_fd < 0 || dup2(2, 1) < 0) fail("cannot set up stdout");
  python = fdopen(protocol_fd, "w");

  elf_firmware_t firmware;
  memset(&firmware, 0, sizeof firmware);
  if (elf_read_firmware(argv[1], &firmware) != 0) fail("cannot read the firmware");
  avr = avr_make_mcu_by_name("atmega328p");
  if (!avr) fail("simavr has no atmega328p");
  avr_init(avr);
  avr_load_firmware(avr, &firmware);
  avr->frequency = 16000000;
  avr->vcc = avr->avcc = avr->aref = SUPPLY;

  memset(terminal_at, -1, sizeof terminal_at);
  static const uint8_t terminal_map[TERMINALS] = TERMINAL_MAP;
  for (int t = 0; t < TERMINALS; t++) terminal_at[terminal_map[t] >> 4][terminal_map[t] & 0x0F] = t;
  watch(PIN_STEP);
  watch(PIN_DIR);
  for (int i = 0; i < 4; i++) watch(select_pins[i]);
  for (int mux = 0; mux < MULTIPLEXERS; mux++) {
    if (MULTIPLEXERS_USED & (1 << mux)) watch(mux_enable[mux]);
  }
  avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_OUT_TRIGGER),
                          conversion, NULL);

  uart_pty_init(avr, &pty);
  uart_pty_connect(&pty, '0');
  follow_pty();
  fprintf(python, "PTY %s\n", link_path);
  fflush(python);

  for (;;) {
    // uart_pty hands the board's output to the pty from its own thread, through a 512-byte
    // FIFO that drops what does not fit. A thread starved of the CPU (a busy machine) would
    // lose bytes no real USB bridge loses: the board waits for it instead, as emulated
    // time may (the host sees a slower board, never a corrupted one).
    const unsigned fifo = sizeof pty.pty.in.buffer;  // a power of two
    while (((pty.pty.in.write - pty.pty.in.read) & (fifo - 1)) > fifo / 2) usleep(200);
    const int state = avr_run(avr);
    if (state == cpu_Done || state == cpu_Crashed) fail("the firmware stopped");
    if (reset_asked) {
      reset_asked = 0;
      if (vanish_ms >= 0) vanish(vanish_ms);
      vanish_ms = -1;
      avr_reset(avr);
      terminal = -1;
      frame_due = 0;
      select_bits = 0;
      memset(enabled, 0, sizeof enabled);
      // The clamp stays where it is; the firmware counts from 0 again (board.h: no home).
    }
  }
}
