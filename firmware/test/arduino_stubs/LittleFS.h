/* Stand-in for PJRC's LittleFS library (LittleFS.h, and File from the teensy4 core's FS.h): the
 * calls the Teensy sketch makes. The real LittleFS::open allocates its file on the heap (malloc
 * and new, once, in setup()); these stand-ins do not, so the heap check of `make teensy` covers
 * the sketch and the core, not PJRC's code. See Arduino.h for what these stand-ins are for. */
#ifndef GRASS_STUB_LITTLEFS_H
#define GRASS_STUB_LITTLEFS_H
#include <Arduino.h>

#define FILE_READ 0
#define FILE_WRITE 1
#define FILE_WRITE_BEGIN 2

class File {
public:
    constexpr File() : f_(nullptr) {}
    explicit File(void *impl) : f_(impl) {}
    File(const File &other);
    File &operator=(const File &other);
    ~File();
    size_t read(void *buf, size_t nbyte);
    size_t write(const void *buf, size_t size);
    void flush();
    bool truncate(uint64_t size = 0);
    bool seek(uint64_t pos);
    uint64_t size();
    operator bool();

private:
    void *f_;
};

class LittleFS_Program {
public:
    constexpr LittleFS_Program() {}
    bool begin(uint32_t size);
    File open(const char *filepath, uint8_t mode = FILE_READ);
};

#endif
