/* Stand-in headers for compiling the Teensy 4.1 sketch (ports/teensy41) in CI without
 * Teensyduino: exactly the Arduino and PJRC calls the sketch makes, declared with the
 * signatures of PJRC's teensy4 core (cores/teensy4: core_pins.h, usb_serial.h,
 * HardwareSerial.h, Stream.h). Declarations only: the bodies live in stand_ins.cpp, another
 * translation unit, so the compiler cannot see through them and drop the sketch's code.
 *
 * As the Arduino builder does, `make teensy` passes `-include Arduino.h` to the sketch.
 * What a compile against these headers does and does not prove: firmware/README.md. */
#ifndef GRASS_STUB_ARDUINO_H
#define GRASS_STUB_ARDUINO_H
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#define LOW 0
#define HIGH 1
#define INPUT 0
#define OUTPUT 1

#ifdef __cplusplus
extern "C" {
#endif
/* core_pins.h (millis and digitalWriteFast are inline there, reading the SysTick count and
 * writing the GPIO set/clear registers) */
uint32_t millis(void);
void pinMode(uint8_t pin, uint8_t mode);
void digitalWriteFast(uint8_t pin, uint8_t val);
void analogWrite(uint8_t pin, int val);
uint32_t analogWriteResolution(uint32_t bits);
void analogWriteFrequency(uint8_t pin, float frequency);
#ifdef __cplusplus
}

/* usb_serial.h: the USB CDC port (`Serial`) */
class usb_serial_class {
public:
    constexpr usb_serial_class() {}
    void begin(long baud);
    int available();
    void flush();
    size_t write(const uint8_t *buffer, size_t size);
    size_t readBytes(char *buffer, size_t length);
};
extern usb_serial_class Serial;

/* HardwareSerial.h: the LPUARTs (`Serial1`, with an RS-485 driver's DE pin) */
class HardwareSerial {
public:
    constexpr HardwareSerial() {}
    void begin(uint32_t baud, uint16_t format = 0);
    void transmitterEnable(uint8_t pin);
    int available();
    void flush();
    size_t write(const uint8_t *buffer, size_t size);
    size_t readBytes(char *buffer, size_t length);
};
extern HardwareSerial Serial1;

void setup(void);
void loop(void);
#endif

#endif
