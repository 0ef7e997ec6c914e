/* Stand-in for PJRC's Encoder library (Encoder.h): the calls the Teensy sketch makes.
 * The real constructor sets both pins to INPUT_PULLUP and attaches a CHANGE interrupt to each;
 * read() masks interrupts, reads the count and ends with interrupts() (the sketch puts its
 * caller's PRIMASK back after it). See Arduino.h for what these stand-ins are for. */
#ifndef GRASS_STUB_ENCODER_H
#define GRASS_STUB_ENCODER_H
#include <Arduino.h>

class Encoder {
public:
    Encoder(uint8_t pin1, uint8_t pin2);
    int32_t read();

private:
    uint8_t pin1_, pin2_;
    volatile int32_t position_;
};

#endif
