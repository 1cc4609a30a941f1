// The rig: pin map, timing and limits of the eskin board (Arduino Uno, ATmega328P, 16 MHz).
//
//   terminal → 74HC4067 (×2 to ×4) → CAV424 → A0    stepper driver → M8 lead screw → clamp
//
// The board is built for one row/column skin of ROWS × COLUMNS terminals: skin.h, which
// the Makefile generates from them (python -m eskin.device.firmware; `make ROWS=8
// COLUMNS=8` builds into build/8x8/), gives TERMINALS and each terminal's multiplexer and
// channel. The multiplexers share their four select lines; each has its own enable
// (active low), so exactly one terminal reaches the CAV424 at a time: multiplexer 0
// carries x1..x16 on its channels 0..15, multiplexer 1 y1..y16, multiplexer 2 x17..x32,
// multiplexer 3 y17..y32; a skin of at most 16 rows and 16 columns (the paper's 10 × 10)
// needs only the first two. The CAV424 turns the terminal's capacitance into a voltage,
// which the ADC reads against AVcc (5 V, 10 bits). The emulation harness (and any bench
// wiring) follows exactly this table.
//
// Where the ATmega328P's limits are (the 32 × 32 build is the largest skin eskin declares):
// * pins: the Uno's 20 are D0/D1 (USB serial), D2..D10 (clamp, select lines, first two
//   enables), D11/D12 (the third and fourth enables) and A0 (the CAV424); D13 and A1..A5
//   stay free. More than 32 rows or columns would need a fifth select line or a 32-channel
//   multiplexer per axis, not more pins.
// * SRAM (2 KiB): .data + .bss (the 257-byte command line, the serial buffers, the core's
//   own) take 955 bytes for 10 × 10 and 961 for 32 × 32; the frame, formatted whole
//   before it is sent, takes 28 + 5 × TERMINALS bytes of stack (128 for 20 terminals,
//   348 for 64), well within the kilobyte left.
// * flash (32 KiB, 0.5 KiB of it the bootloader): 5,754 bytes for 10 × 10, 5,804 for
//   32 × 32; the terminal map is one byte per terminal.
// * time: a frame is TERMINALS × (SETTLE_US + 2 × 104 µs): 12 ms for 20 terminals, 39 ms
//   for 64; at 115200 baud its line (up to 346 bytes) takes 30 ms, within the next scan.
#ifndef ESKIN_BOARD_H
#define ESKIN_BOARD_H

#include "skin.h"

#define ESKIN_FIRMWARE "fw-1.0.0"
#define ESKIN_BAUD 115200

// ---------------------------------------------------------------- pins (Arduino numbers)
#define PIN_MUX_S0 4       // PD4 \ select lines, shared by every multiplexer:
#define PIN_MUX_S1 5       // PD5 |  channel = S3 S2 S1 S0 (S0 the least significant bit)
#define PIN_MUX_S2 6       // PD6 |
#define PIN_MUX_S3 7       // PD7 /
#define PIN_MUX_X_EN 8     // PB0, low: multiplexer 0 (x1..x16) drives the CAV424
#define PIN_MUX_Y_EN 9     // PB1, low: multiplexer 1 (y1..y16) drives the CAV424
#define PIN_MUX_X2_EN 11   // PB3, low: multiplexer 2 (x17..x32) drives the CAV424
#define PIN_MUX_Y2_EN 12   // PB4, low: multiplexer 3 (y17..y32) drives the CAV424
#define MUX_ENABLE_PINS { PIN_MUX_X_EN, PIN_MUX_Y_EN, PIN_MUX_X2_EN, PIN_MUX_Y2_EN }
#define PIN_CAV424 A0      // ADC0: the CAV424's output voltage
#define PIN_STEP 2         // PD2: one step of the clamp's stepper per rising edge
#define PIN_DIR 3          // PD3: high = extend (stretch), low = retract
#define PIN_STEPPER_EN 10  // PB2, low: driver enabled

// ---------------------------------------------------------------- read-out timing
// After switching the multiplexer the CAV424's output filter needs time to follow the
// new terminal; then one conversion is thrown away (the sample-and-hold saw the old
// channel's charge) and one kept. The ADC runs at 16 MHz / 128 = 125 kHz (the Arduino
// core's prescaler): 13 ADC clocks, 104 µs a conversion. A frame: TERMINALS ×
// (SETTLE_US + 2 × 104 µs), 12 ms for 20 terminals, the frame period of the Python board.
#define SETTLE_US 400

// ---------------------------------------------------------------- the clamp
// 200 full steps a turn, 16 microsteps, M8 coarse thread (1.25 mm a turn):
// 2560 steps per mm. Position 0 is the clamp at rest, where it must be at power-up
// (the paper's rig has no home switch).
#define STEPS_PER_MM 2560L
#define MAX_EXTENSION_UM 40000L    // 40 mm, as the Python board (MAX_EXTENSION_MM)
#define STEP_PERIOD_US 100         // 10 kHz step rate: 3.9 mm/s

// ---------------------------------------------------------------- protocol limits
#define MAX_SAMPLE 100000UL        // as the Python board (MAX_SAMPLE)
#define LINE_MAX 256               // longest command line, as the host (MAX_LINE_BYTES)
// A frame line: "D," + 2 × (10 digits + ',') + TERMINALS × 4 digits + TERMINALS - 1
// commas + "*CC\n" and the NUL that ends the string.
#define FRAME_BYTES (28 + 5 * TERMINALS)
#define ID_MAX 24                  // device id: letters, digits, '-' and '_'

// EEPROM: the device id, written once by `ID <id>` (a provisioning command of this
// firmware, outside protocol v1): a magic byte, the length, the characters.
#define EEPROM_ID_MAGIC 0xE5
#define EEPROM_ID_ADDRESS 0

#endif
