// The rig: pin map, timing and limits of the eskin board (Arduino Uno, ATmega328P, 16 MHz).
//
//   terminal → 74HC4067 (×2) → CAV424 → A0        stepper driver → M8 lead screw → clamp
//
// Both multiplexers share their four select lines; each has its own enable (active low),
// so exactly one terminal reaches the CAV424 at a time: x1..x10 are channels 0..9 of the
// x multiplexer, y1..y10 channels 0..9 of the y multiplexer. The CAV424 turns that
// terminal's capacitance into a voltage, which the ADC reads against AVcc (5 V, 10 bits).
// The emulation harness (and any bench wiring) follows exactly this table.
#ifndef ESKIN_BOARD_H
#define ESKIN_BOARD_H

#define ESKIN_FIRMWARE "fw-1.0.0"
#define ESKIN_BAUD 115200

// ---------------------------------------------------------------- pins (Arduino numbers)
#define PIN_MUX_S0 4       // PD4 \ select lines, shared by both multiplexers:
#define PIN_MUX_S1 5       // PD5 |  channel = S3 S2 S1 S0 (S0 the least significant bit)
#define PIN_MUX_S2 6       // PD6 |
#define PIN_MUX_S3 7       // PD7 /
#define PIN_MUX_X_EN 8     // PB0, low: the x multiplexer drives the CAV424
#define PIN_MUX_Y_EN 9     // PB1, low: the y multiplexer drives the CAV424
#define PIN_CAV424 A0      // ADC0: the CAV424's output voltage
#define PIN_STEP 2         // PD2: one step of the clamp's stepper per rising edge
#define PIN_DIR 3          // PD3: high = extend (stretch), low = retract
#define PIN_STEPPER_EN 10  // PB2, low: driver enabled

// ---------------------------------------------------------------- read-out timing
// After switching the multiplexer the CAV424's output filter needs time to follow the
// new terminal; then one conversion is thrown away (the sample-and-hold saw the old
// channel's charge) and one kept. The ADC runs at 16 MHz / 128 = 125 kHz (the Arduino
// core's prescaler): 13 ADC clocks, 104 µs a conversion. A frame: 20 × (SETTLE_US + 2 ×
// 104 µs) ≈ 12 ms, about the 12 ms frame period of the Python board.
#define SETTLE_US 400
#define TERMINALS 20

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
#define ID_MAX 24                  // device id: letters, digits, '-' and '_'

// EEPROM: the device id, written once by `ID <id>` (a provisioning command of this
// firmware, outside protocol v1): a magic byte, the length, the characters.
#define EEPROM_ID_MAGIC 0xE5
#define EEPROM_ID_ADDRESS 0

#endif
