// The eskin board under emulation: simavr runs the compiled firmware, its UART on a
// pseudo-terminal (simavr's uart_pty part), and this harness plays the rig around it.
//
//   eskin_emulator <firmware.elf> <link>
//
// <link> is a symlink that follows the firmware's pty, as udev's /dev/serial/by-id/ names
// follow a board that is unplugged and plugged back.
// It watches the pins of board.h: the multiplexers' select and enable lines (which terminal
// reaches the CAV424) and the stepper's STEP and DIR (where the clamp is). Each ADC
// conversion is answered with the voltage of the selected terminal. The voltages come
// from the skin model, which lives in the Python process that started this one, over
// stdin/stdout, one line each way:
//
//   → PTY <link>                the firmware's serial port, once, at start
//   → FRAME <steps>             a scan begins (x1 selected); the clamp's position in steps
//   ← VOLTS <v1> ... <v20>      that scan's 20 voltages, in units of 5 V / 65535
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

#define TERMINALS 20
// board.h's pins, by port and bit
#define STEP_BIT 2   // PD2
#define DIR_BIT 3    // PD3
#define S0_BIT 4     // PD4..PD7: the select lines
#define X_EN_BIT 0   // PB0
#define Y_EN_BIT 1   // PB1
// Units of the voltages simavr's ADC is given: it keeps them in 16 bits, so 5 V (the
// supply, AVcc) is 65535 units of 76.3 µV.
#define SUPPLY 65535

static avr_t *avr;
static FILE *python;           // the protocol's output (stdout before it was redirected)
static uint32_t volts[TERMINALS];
static int terminal = -1;      // the terminal that reaches the CAV424, -1 for none
static int select_bits = 0, x_enabled = 0, y_enabled = 0, extending = 0;
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
  char line[512];
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
  if (strncmp(at, "VOLTS ", 6) != 0) fail("expected VOLTS <20 numbers>");
  at += 6;
  for (int i = 0; i < TERMINALS; i++) {
    char *end;
    unsigned long v = strtoul(at, &end, 10);
    if (end == at || v > SUPPLY) fail("VOLTS needs 20 numbers in 0..65535 (5 V / 65535)");
    volts[i] = (uint32_t)v;
    at = end;
  }
}

static void update_terminal(void) {
  int now = -1;
  if (x_enabled && !y_enabled && select_bits < 10) now = select_bits;
  if (y_enabled && !x_enabled && select_bits < 10) now = 10 + select_bits;
  if (now == 0 && terminal != 0) frame_due = 1;
  terminal = now;
}

static void port_d(struct avr_irq_t *irq, uint32_t value, void *param) {
  (void)param;
  const int bit = (int)irq->irq;
  if (bit == STEP_BIT) {
    if (value) position_steps += extending ? 1 : -1;  // a rising edge is a step
  } else if (bit == DIR_BIT) {
    extending = value != 0;
  } else if (bit >= S0_BIT && bit < S0_BIT + 4) {
    const int mask = 1 << (bit - S0_BIT);
    select_bits = value ? (select_bits | mask) : (select_bits & ~mask);
    update_terminal();
  }
}

static void port_b(struct avr_irq_t *irq, uint32_t value, void *param) {
  (void)param;
  if (irq->irq == X_EN_BIT) x_enabled = value == 0;  // enables are active low
  if (irq->irq == Y_EN_BIT) y_enabled = value == 0;
  update_terminal();
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

  for (int bit = STEP_BIT; bit <= S0_BIT + 3; bit++)
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), bit), port_d, NULL);
  for (int bit = X_EN_BIT; bit <= Y_EN_BIT; bit++)
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('B'), bit), port_b, NULL);
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
      select_bits = x_enabled = y_enabled = 0;
      // The clamp stays where it is; the firmware counts from 0 again (board.h: no home).
    }
  }
}
