// Bodies for the stand-in headers of this folder, and a reset handler, so that the Teensy 4.1
// sketch links into an image that `make teensy` can size and search for heap symbols. They do
// nothing a board would: no register is touched, no byte is sent, storage is absent.
// See Arduino.h for what these stand-ins are for.
#include <Arduino.h>
#include <Encoder.h>
#include <IntervalTimer.h>
#include <LittleFS.h>

// A counter each stand-in bumps, so that none is folded away into nothing.
static volatile uint32_t calls;

extern "C" {
uint32_t millis(void) { return calls++; }
void pinMode(uint8_t, uint8_t) { calls++; }
void digitalWriteFast(uint8_t, uint8_t) { calls++; }
void analogWrite(uint8_t, int) { calls++; }
uint32_t analogWriteResolution(uint32_t bits) { calls++; return bits; }
void analogWriteFrequency(uint8_t, float) { calls++; }
}

void usb_serial_class::begin(long) { calls++; }
int usb_serial_class::available() { return 0; }
void usb_serial_class::flush() { calls++; }
size_t usb_serial_class::write(const uint8_t *, size_t size) { calls++; return size; }
size_t usb_serial_class::readBytes(char *, size_t) { return 0; }
usb_serial_class Serial;

void HardwareSerial::begin(uint32_t, uint16_t) { calls++; }
void HardwareSerial::transmitterEnable(uint8_t) { calls++; }
int HardwareSerial::available() { return 0; }
void HardwareSerial::flush() { calls++; }
size_t HardwareSerial::write(const uint8_t *, size_t size) { calls++; return size; }
size_t HardwareSerial::readBytes(char *, size_t) { return 0; }
HardwareSerial Serial1;

Encoder::Encoder(uint8_t pin1, uint8_t pin2) : pin1_(pin1), pin2_(pin2), position_(0) { calls++; }
int32_t Encoder::read() { return position_; }

IntervalTimer::~IntervalTimer() { end(); }
bool IntervalTimer::begin(callback_t funct, uint32_t) { calls++; return funct != nullptr; }
void IntervalTimer::priority(uint8_t n) { nvic_priority_ = n; }
void IntervalTimer::end() { calls++; }

File::File(const File &other) : f_(other.f_) {}
File &File::operator=(const File &other) { f_ = other.f_; return *this; }
File::~File() { f_ = nullptr; }
size_t File::read(void *, size_t) { return 0; }
size_t File::write(const void *, size_t) { return 0; }
void File::flush() { calls++; }
bool File::truncate(uint64_t) { return false; }
bool File::seek(uint64_t) { return false; }
uint64_t File::size() { return 0; }
File::operator bool() { return f_ != nullptr; }

bool LittleFS_Program::begin(uint32_t) { return false; }   // no flash: the sketch's nv_fail path
File LittleFS_Program::open(const char *, uint8_t) { return File(); }

// ---- start-up: what the teensy4 core's startup.c does before main, in short ----
extern "C" {
extern uint32_t __stack_top[], __data_load[], __data_start[], __data_end[], __bss_start[],
    __bss_end[];
extern void (*__init_array_start[])(void);
extern void (*__init_array_end[])(void);
// what crtbegin.o defines (not linked: -nostartfiles), named by the registration of the
// destructors of static objects
void *__dso_handle = nullptr;
void Reset_Handler(void);
}

struct vector_table {
    uint32_t *initial_sp;
    void (*reset)(void);
};
__attribute__((section(".vectors"), used)) static const vector_table vectors = {__stack_top,
                                                                               Reset_Handler};

extern "C" void Reset_Handler(void)
{
    for (uint32_t *src = __data_load, *dst = __data_start; dst < __data_end;)
        *dst++ = *src++;
    for (uint32_t *dst = __bss_start; dst < __bss_end;)
        *dst++ = 0;
    for (void (**ctor)(void) = __init_array_start; ctor < __init_array_end; ctor++)
        (*ctor)();
    setup();
    for (;;)
        loop();
}
