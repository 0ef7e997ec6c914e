/* Stand-in for the teensy4 core's IntervalTimer.h: the calls the Teensy sketch makes (the real
 * begin() takes any arithmetic period in microseconds and an inplace_function callback, which a
 * plain function converts to). See Arduino.h for what these stand-ins are for. */
#ifndef GRASS_STUB_INTERVALTIMER_H
#define GRASS_STUB_INTERVALTIMER_H
#include <Arduino.h>

class IntervalTimer {
public:
    using callback_t = void (*)(void);
    constexpr IntervalTimer() {}
    ~IntervalTimer();
    bool begin(callback_t funct, uint32_t microseconds);
    void priority(uint8_t n);
    void end();

private:
    uint8_t nvic_priority_ = 128;
};

#endif
