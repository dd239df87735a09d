// Internal to the builder: little-endian byte and bit streams for the page file (pages.cpp, cluster_*.cpp).
// Readers check every read against the end and throw PageFileError naming the place: a truncated or corrupt
// stream is an error, never a read past the data.
#pragma once

#include "tessera/builder.h"

#include <algorithm>
#include <cstring>
#include <utility>

namespace tessera {

class ByteWriter {
public:
    template <typename T>
    void put(const T& value) {
        const size_t at = bytes.size();
        bytes.resize(at + sizeof(T));
        std::memcpy(&bytes[at], &value, sizeof(T));
    }
    void put_varint(uint32_t value) {  // LEB128: 7 bits a byte, small values in one byte
        for (; value >= 0x80; value >>= 7) bytes.push_back(uint8_t(value | 0x80));
        bytes.push_back(uint8_t(value));
    }
    std::vector<uint8_t> bytes;
};

class ByteReader {
public:
    ByteReader(std::span<const uint8_t> bytes, std::string where) : bytes_(bytes), where_(std::move(where)) {}
    template <typename T>
    T get() {
        need(sizeof(T));
        T value;
        std::memcpy(&value, &bytes_[at_], sizeof(T));
        at_ += sizeof(T);
        return value;
    }
    uint32_t get_varint() {
        uint32_t value = 0;
        for (int shift = 0; shift < 35; shift += 7) {
            const uint8_t byte = get<uint8_t>();
            value |= uint32_t(byte & 0x7f) << shift;
            if (!(byte & 0x80)) return value;
        }
        throw PageFileError(where_ + ": a number runs over 5 bytes");
    }
    std::span<const uint8_t> take(size_t n) {
        need(n);
        at_ += n;
        return bytes_.subspan(at_ - n, n);
    }
    bool done() const { return at_ == bytes_.size(); }

private:
    void need(size_t n) {
        if (n > bytes_.size() - at_) throw PageFileError(where_ + ": data ends early");
    }
    std::span<const uint8_t> bytes_;
    std::string where_;
    size_t at_ = 0;
};

// LSB-first bit stream; flush() pads to a byte.
class BitWriter {
public:
    void put(uint64_t value, uint32_t bits) {  // bits <= 64
        if (bits == 0) return;
        if (bits < 64) value &= (1ull << bits) - 1;
        pending_ |= value << count_;
        if (count_ + bits < 64) {
            count_ += bits;
            return;
        }
        const uint32_t carried = count_ + bits - 64;  // the bits of value that did not fit
        drain(8);
        pending_ = carried ? value >> (bits - carried) : 0;
        count_ = carried;
    }
    void flush() { drain((count_ + 7) / 8); }
    std::vector<uint8_t> bytes;

private:
    void drain(uint32_t byteCount) {
        const size_t at = bytes.size();
        bytes.resize(at + byteCount);
        std::memcpy(&bytes[at], &pending_, byteCount);  // little-endian: the first bits first
        pending_ = 0;
        count_ = 0;
    }
    uint64_t pending_ = 0;
    uint32_t count_ = 0;
};

class BitReader {
public:
    BitReader(std::span<const uint8_t> bytes, std::string where) : bytes_(bytes), where_(std::move(where)) {}
    uint64_t get(uint32_t bits) {  // bits <= 56
        if (count_ < bits) refill();
        if (count_ < bits) throw PageFileError(where_ + ": bit data ends early");
        const uint64_t value = pending_ & ((1ull << bits) - 1);
        pending_ >>= bits;
        count_ -= bits;
        return value;
    }
    void skip_to_byte() {
        pending_ >>= count_ % 8;
        count_ -= count_ % 8;
    }
    size_t bytes_left() const { return bytes_.size() - at_ + count_ / 8; }

private:
    void refill() {
        if (bytes_.size() - at_ >= 8) {  // eight bytes at once; bits past the whole bytes are loaded again next time
            uint64_t word;
            std::memcpy(&word, &bytes_[at_], 8);
            pending_ |= word << count_;
            const uint32_t taken = (63 - count_) / 8;
            at_ += taken;
            count_ += 8 * taken;
            return;
        }
        while (count_ <= 56 && at_ < bytes_.size()) {
            pending_ |= uint64_t(bytes_[at_++]) << count_;
            count_ += 8;
        }
    }
    std::span<const uint8_t> bytes_;
    std::string where_;
    size_t at_ = 0;
    uint64_t pending_ = 0;
    uint32_t count_ = 0;
};

inline uint64_t zigzag(int64_t v) { return (uint64_t(v) << 1) ^ uint64_t(v >> 63); }
inline int64_t unzigzag(uint64_t v) { return int64_t(v >> 1) ^ -int64_t(v & 1); }

}  // namespace tessera
