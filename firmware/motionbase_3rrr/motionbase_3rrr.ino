// motionbase 3-RRR servo firmware (Arduino Uno/Nano).
//
// Protocol (thesis appendix A.3): the decimal digits of an angle in integer degrees followed
// by 'p', 'q' or 'r' for servo 1, 2 or 3, e.g. "90p45q120r", at 19200 baud. The sketch prints
// "Rolling" once ready (after the reset that opening the port causes).
//
// Improved over the thesis's sketch, where a stray byte could move a servo:
//   - a value above 180 is ignored (the thesis wrote it, and Servo.write() takes values
//     above 180 as microseconds);
//   - a letter with no digits before it is ignored (the thesis wrote 0 degrees);
//   - a number interrupted by any other byte is discarded with the rest of its command (up to
//     the next letter), so noise in "90p" cannot become "0p"; bytes between commands
//     ('\r', '\n', spaces) are ignored;
//   - more than 3 digits invalidate the number (no int overflow);
//   - servos are attached only after the first valid command for each, so a reset does not
//     throw the arms to a default angle before the host speaks.
// motionbase.io.servo_protocol.ServoDecoder implements the same state machine for tests.

#include <Servo.h>

const long BAUD = 19200;
const int SERVO_PINS[3] = {9, 6, 5};  // servo 1, 2, 3 as in the thesis
const int MAX_DEG = 180;
const int MAX_DIGITS = 3;

Servo servos[3];
bool attached[3] = {false, false, false};
int value = 0;   // number being read
int digits = 0;  // digits read since the last letter or stray byte
bool poisoned = false;  // a stray byte broke the current command: drop it at its letter

void setup() {
  Serial.begin(BAUD);
  Serial.println("Rolling");
}

void command(int index) {
  if (!poisoned && digits > 0 && digits <= MAX_DIGITS && value <= MAX_DEG) {
    if (!attached[index]) {
      servos[index].attach(SERVO_PINS[index]);
      attached[index] = true;
    }
    servos[index].write(value);
  }
  value = 0;
  digits = 0;
  poisoned = false;
}

void loop() {
  while (Serial.available() > 0) {
    int ch = Serial.read();
    if (ch >= '0' && ch <= '9') {
      if (digits <= MAX_DIGITS) {
        value = value * 10 + (ch - '0');
      }
      if (digits < 100) digits++;  // bounded: any count above 3 is invalid anyway
    } else if (ch == 'p') {
      command(0);
    } else if (ch == 'q') {
      command(1);
    } else if (ch == 'r') {
      command(2);
    } else if (digits > 0) {
      poisoned = true;  // stray byte inside a number: drop this command
      value = 0;
      digits = 0;
    }
  }
}
