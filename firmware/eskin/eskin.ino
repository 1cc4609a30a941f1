// eskin board firmware: wire protocol v1 (docs/protocol.md) on an Arduino Uno.
//
// Board → host: #HELLO at start and on HELLO; D,<seq>,<t_ms>,<x1..xR>,<y1..yC>*<CC>
// frames (CC: CRC-8, polynomial 0x07, init 0x00, of every byte before '*'); #OK / #ERR.
// R and C are the skin it is built for (board.h, skin.h).
// Host → board: HELLO, STRETCH <mm>, SAMPLE <n>, STREAM ON|OFF. SIM commands belong to
// the simulated board: here indenters are placed by hand, so they are an #ERR. ID <id>
// writes the device id to EEPROM once (provisioning; not part of protocol v1).
//
// Commands are answered in the order they arrive: a line that arrives while a SAMPLE is
// still owed waits until its #OK SAMPLE has gone. While streaming, commands are
// answered between frames. Pin map, timing and limits: board.h.

#include <avr/eeprom.h>
#include <avr/pgmspace.h>

#include "board.h"

#define TEXT_(value) #value
#define TEXT(value) TEXT_(value)

static const uint8_t mux_enable[] = MUX_ENABLE_PINS;
static const uint8_t terminal_map[TERMINALS] PROGMEM = TERMINAL_MAP;

static uint32_t seq = 0;            // frame counter: never repeats within a power cycle
static uint32_t owed = 0;           // frames of the SAMPLE being answered
static uint32_t asked = 0;          // its n, for the #OK
static bool streaming = false;
// The clamp, in steps from rest. The Uno resets whenever the host opens its port, and the
// clamp stays where it was: the position lives in RAM the C runtime leaves alone through a
// reset, beside a check word. At power-up the check fails and the clamp must be at rest
// (board.h: no home switch).
static int32_t position_steps __attribute__((section(".noinit")));
static uint32_t position_check __attribute__((section(".noinit")));
#define POSITION_CHECK(steps) ((uint32_t)(steps) ^ 0xA5E5C1D2UL)

static char line[LINE_MAX + 1];     // the command being received
static uint16_t line_length = 0;
static bool line_too_long = false;
static bool line_ready = false;

static char device_id[ID_MAX + 1];

// ---------------------------------------------------------------- output

static uint8_t crc8(const char *data, uint16_t length) {
  uint8_t crc = 0;
  for (uint16_t i = 0; i < length; i++) {
    crc ^= (uint8_t)data[i];
    for (uint8_t bit = 0; bit < 8; bit++) {
      crc = (crc & 0x80) ? (uint8_t)((crc << 1) ^ 0x07) : (uint8_t)(crc << 1);
    }
  }
  return crc;
}

static void send(const char *text) { Serial.write(text); }

static void send_line(const char *a, const char *b = "", const char *c = "",
                      const char *d = "") {
  send(a); send(b); send(c); send(d);
  send("\n");
}

static void hello() {
  send_line("#HELLO eskin " ESKIN_FIRMWARE SKIN_TAG " terminals=" TEXT(TERMINALS)
            " adc_bits=10 id=", device_id);
}

// ---------------------------------------------------------------- the read-out

static void disable_multiplexers() {
  for (uint8_t mux = 0; mux < sizeof mux_enable; mux++) {
    if (MULTIPLEXERS_USED & (1 << mux)) digitalWrite(mux_enable[mux], HIGH);
  }
}

static void select_terminal(uint8_t terminal) {  // 0..ROWS-1: x1.., then y1..
  const uint8_t entry = pgm_read_byte(&terminal_map[terminal]);
  const uint8_t channel = entry & 0x0F;
  disable_multiplexers();  // all off while the select lines change
  digitalWrite(PIN_MUX_S0, channel & 1 ? HIGH : LOW);
  digitalWrite(PIN_MUX_S1, channel & 2 ? HIGH : LOW);
  digitalWrite(PIN_MUX_S2, channel & 4 ? HIGH : LOW);
  digitalWrite(PIN_MUX_S3, channel & 8 ? HIGH : LOW);
  digitalWrite(mux_enable[entry >> 4], LOW);
}

static uint16_t read_terminal(uint8_t terminal) {
  select_terminal(terminal);
  delayMicroseconds(SETTLE_US);
  analogRead(PIN_CAV424);  // the sample-and-hold still carries the last channel
  return (uint16_t)analogRead(PIN_CAV424);
}

static void send_frame() {
  char frame[FRAME_BYTES];
  char *end = frame;
  const uint32_t t_ms = millis();
  *end++ = 'D';
  *end++ = ',';
  ultoa(seq, end, 10);
  end += strlen(end);
  *end++ = ',';
  ultoa(t_ms, end, 10);
  end += strlen(end);
  for (uint8_t terminal = 0; terminal < TERMINALS; terminal++) {
    *end++ = ',';
    utoa(read_terminal(terminal), end, 10);
    end += strlen(end);
  }
  static const char hex[] = "0123456789ABCDEF";
  const uint8_t crc = crc8(frame, (uint16_t)(end - frame));
  *end++ = '*';
  *end++ = hex[crc >> 4];
  *end++ = hex[crc & 0x0F];
  *end++ = '\n';
  *end = '\0';
  send(frame);
  seq++;
}

// ---------------------------------------------------------------- the clamp

static void move_to(int32_t steps) {
  digitalWrite(PIN_DIR, steps > position_steps ? HIGH : LOW);
  digitalWrite(PIN_STEPPER_EN, LOW);
  while (position_steps != steps) {
    digitalWrite(PIN_STEP, HIGH);
    delayMicroseconds(2);  // the driver's minimum pulse is 1 µs
    digitalWrite(PIN_STEP, LOW);
    position_steps += steps > position_steps ? 1 : -1;
    position_check = POSITION_CHECK(position_steps);
    delayMicroseconds(STEP_PERIOD_US - 2);
  }
}

// ---------------------------------------------------------------- parsing

// Unsigned decimal, digits only; false if empty, not digits, or beyond 10^9.
static bool parse_count(const char *text, uint32_t *value) {
  uint32_t v = 0;
  if (!*text) return false;
  for (; *text; text++) {
    if (*text < '0' || *text > '9' || v > 100000000UL) return false;
    v = v * 10 + (uint32_t)(*text - '0');
  }
  *value = v;
  return true;
}

// Millimetres as [digits][.digits] to micrometres (digits past the third decimal are
// ignored); false if not a number or beyond 10^6 mm.
static bool parse_mm(const char *text, uint32_t *micrometres) {
  uint32_t whole = 0, fraction = 0, scale = 1000;
  bool digits = false;
  for (; *text && *text != '.'; text++) {
    if (*text < '0' || *text > '9' || whole > 1000000UL) return false;
    whole = whole * 10 + (uint32_t)(*text - '0');
    digits = true;
  }
  if (*text == '.') {
    for (text++; *text; text++) {
      if (*text < '0' || *text > '9') return false;
      if (scale > 1) {
        scale /= 10;
        fraction += (uint32_t)(*text - '0') * scale;
      }
      digits = true;
    }
  }
  if (!digits) return false;
  *micrometres = whole * 1000 + fraction;
  return true;
}

static bool id_character(char c) {
  return (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') ||
         c == '-' || c == '_';
}

static void load_id() {
  const uint8_t *at = (const uint8_t *)EEPROM_ID_ADDRESS;
  const uint8_t length = eeprom_read_byte(at + 1);
  if (eeprom_read_byte(at) != EEPROM_ID_MAGIC || length == 0 || length > ID_MAX) {
    strcpy(device_id, "unset");
    return;
  }
  for (uint8_t i = 0; i < length; i++) device_id[i] = (char)eeprom_read_byte(at + 2 + i);
  device_id[length] = '\0';
}

// ---------------------------------------------------------------- commands

static bool same(const char *word, const char *name) { return strcasecmp(word, name) == 0; }

static void not_a_number(const char *name, const char *text) {
  send("#ERR ");  // as the Python board: #ERR SAMPLE 'abc' is not a number
  send(name);
  send_line(" '", text, "' is not a number");
}

static void handle(char *text) {
  char *words[4];
  uint8_t count = 0;
  for (char *word = strtok(text, " \t\r"); word; word = strtok(NULL, " \t\r")) {
    if (count == 4) { count++; break; }
    words[count++] = word;
  }
  if (count == 0) return;
  char *name = words[0];
  for (char *c = name; *c; c++) *c = toupper(*c);

  if (same(name, "HELLO") && count == 1) {
    hello();
  } else if (same(name, "STRETCH") && count == 2) {
    uint32_t micrometres;
    if (!parse_mm(words[1], &micrometres)) {
      not_a_number(name, words[1]);
    } else if (micrometres > MAX_EXTENSION_UM) {
      send_line("#ERR STRETCH ", words[1], " is outside 0.0..40.0");
    } else {
      move_to((int32_t)((micrometres * STEPS_PER_MM + 500) / 1000));
      send_line("#OK STRETCH ", words[1]);
    }
  } else if (same(name, "SAMPLE") && count == 2) {
    uint32_t n;
    if (!parse_count(words[1], &n)) {
      not_a_number(name, words[1]);
    } else if (n < 1 || n > MAX_SAMPLE) {
      send_line("#ERR SAMPLE ", words[1], " is outside 1..100000");
    } else {
      owed = asked = n;
    }
  } else if (same(name, "STREAM") && count == 2 && (same(words[1], "ON") || same(words[1], "OFF"))) {
    streaming = same(words[1], "ON");
    send_line("#OK STREAM ", streaming ? "ON" : "OFF");
  } else if (same(name, "SIM")) {
    send_line("#ERR SIM not a simulated board: indenters are placed by hand");
  } else if (same(name, "ID") && count == 2) {
    const uint8_t length = strlen(words[1]);
    bool valid = length <= ID_MAX;
    for (uint8_t i = 0; valid && i < length; i++) valid = id_character(words[1][i]);
    if (strcmp(device_id, "unset") != 0) {
      send_line("#ERR ID already set to ", device_id);
    } else if (!valid) {
      send_line("#ERR ID use up to 24 letters, digits, '-' or '_'");
    } else {
      uint8_t *at = (uint8_t *)EEPROM_ID_ADDRESS;
      for (uint8_t i = 0; i < length; i++) eeprom_update_byte(at + 2 + i, (uint8_t)words[1][i]);
      eeprom_update_byte(at + 1, length);
      eeprom_update_byte(at, EEPROM_ID_MAGIC);  // last: a reset mid-write leaves it unset
      load_id();
      send_line("#OK ID ", device_id);
    }
  } else {
    send_line("#ERR ", name, " unknown command or wrong arguments");
  }
}

// Read what has arrived into `line`, up to one complete line.
static void receive() {
  while (!line_ready && Serial.available() > 0) {
    const char c = (char)Serial.read();
    if (c == '\n') {
      if (line_too_long) {
        send_line("#ERR ? line too long");
        line_too_long = false;
      } else {
        line[line_length] = '\0';
        line_ready = true;
      }
      line_length = 0;
    } else if (!line_too_long) {
      if (line_length == LINE_MAX) {
        line_too_long = true;  // drop the rest of it, up to its newline
      } else {
        line[line_length++] = c;
      }
    }
  }
}

// ---------------------------------------------------------------- Arduino

void setup() {
  pinMode(PIN_MUX_S0, OUTPUT);
  pinMode(PIN_MUX_S1, OUTPUT);
  pinMode(PIN_MUX_S2, OUTPUT);
  pinMode(PIN_MUX_S3, OUTPUT);
  // High before they become outputs: no multiplexer or driver is enabled for an instant.
  disable_multiplexers();
  digitalWrite(PIN_STEPPER_EN, HIGH);
  for (uint8_t mux = 0; mux < sizeof mux_enable; mux++) {
    if (MULTIPLEXERS_USED & (1 << mux)) pinMode(mux_enable[mux], OUTPUT);
  }
  pinMode(PIN_STEPPER_EN, OUTPUT);
  pinMode(PIN_STEP, OUTPUT);
  pinMode(PIN_DIR, OUTPUT);
  if (position_check != POSITION_CHECK(position_steps)) {  // power-up: the clamp at rest
    position_steps = 0;
    position_check = POSITION_CHECK(0);
  }
  load_id();
  Serial.begin(ESKIN_BAUD);
  hello();
}

void loop() {
  receive();
  if (line_ready && owed == 0) {  // in order: after the SAMPLE being answered
    handle(line);
    line_ready = false;
  }
  if (owed > 0) {
    send_frame();
    if (--owed == 0) {
      char n[11];
      ultoa(asked, n, 10);
      send_line("#OK SAMPLE ", n);
    }
  } else if (streaming) {
    send_frame();
  }
}
