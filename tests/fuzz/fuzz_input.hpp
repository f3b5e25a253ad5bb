// The fuzz input read front to back (docs/TESTING.md, "Fuzzing"). Every value has a
// meaning when the bytes run out (zero), so a short input is a valid input, an input of
// zeros is the plainest case, and a seed can be written by hand.
#pragma once

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <string>
#include <vector>

#include "common/core/types.hpp"

namespace deif::fuzz {

class FuzzInput {
 public:
  FuzzInput(const std::uint8_t* data, std::size_t size) : data_(data), size_(size) {}

  bool empty() const { return pos_ >= size_; }
  std::size_t remaining() const { return empty() ? 0 : size_ - pos_; }

  std::uint8_t Byte() { return empty() ? 0 : data_[pos_++]; }
  bool Bool() { return (Byte() & 1u) != 0; }
  std::uint16_t U16() { return static_cast<std::uint16_t>(Byte() | (Byte() << 8)); }
  std::uint32_t U32() { return static_cast<std::uint32_t>(U16()) | (static_cast<std::uint32_t>(U16()) << 16); }
  std::uint64_t U64() { return static_cast<std::uint64_t>(U32()) | (static_cast<std::uint64_t>(U32()) << 32); }

  // An integer: mostly small (around 0, so near the valid ids and steps), sometimes one of
  // the extremes, sometimes any 64-bit pattern.
  std::int64_t Int() {
    const std::uint8_t kind = Byte();
    switch (kind >> 5) {
      case 0:
      case 1:
      case 2:
      case 3: return static_cast<std::int64_t>(kind & 0x3Fu) - 8;  // -8..55
      case 4: return static_cast<std::int64_t>(Byte()) - 128;
      case 5: return static_cast<std::int64_t>(static_cast<std::int16_t>(U16()));
      case 6: {
        constexpr std::int64_t kExtremes[] = {std::numeric_limits<std::int64_t>::min(),
                                             std::numeric_limits<std::int64_t>::max(),
                                             std::numeric_limits<std::int32_t>::min(),
                                             std::numeric_limits<std::int32_t>::max(),
                                             -1, 0, 1, 1LL << 53};
        return kExtremes[kind & 7u];
      }
      default: return static_cast<std::int64_t>(U64());
    }
  }
  int SmallInt() {
    const std::int64_t v = Int();
    if (v < std::numeric_limits<int>::min() || v > std::numeric_limits<int>::max()) {
      return v < 0 ? std::numeric_limits<int>::min() : std::numeric_limits<int>::max();
    }
    return static_cast<int>(v);
  }

  // A double: NaN, infinities, the extremes, the plausibility limits of
  // common/protocol/validation.hpp and their neighbours, round values, or any bit pattern.
  double Double() {
    const std::uint8_t kind = Byte();
    constexpr double kInf = std::numeric_limits<double>::infinity();
    switch (kind % 24) {
      case 0: return 0.0;
      case 1: return std::numeric_limits<double>::quiet_NaN();
      case 2: return kInf;
      case 3: return -kInf;
      case 4: return std::numeric_limits<double>::max();
      case 5: return -std::numeric_limits<double>::max();
      case 6: return std::numeric_limits<double>::denorm_min();
      case 7: return std::numeric_limits<double>::min();
      case 8: return -0.0;
      case 9: return std::nextafter(1e6, Bool() ? kInf : 0.0);       // kMaxCoordinateM, kMaxRangeM
      case 10: return std::nextafter(1e-12, Bool() ? kInf : 0.0);    // kMinVarianceM2
      case 11: return std::nextafter(1e12, Bool() ? kInf : 0.0);     // ContributionLimits
      case 12: return std::nextafter(-1.0, 0.0);                     // cancels a unit entry
      case 13: return 1e300 * (Bool() ? 1.0 : -1.0);
      case 14:
      case 15: {
        std::uint64_t bits = U64();
        double v = 0.0;
        std::memcpy(&v, &bits, sizeof v);
        return v;
      }
      default: {
        // m * 10^e, m in [-128, 127] / 16, e in [-16, 15]: plausible magnitudes.
        const double mantissa = static_cast<double>(static_cast<std::int8_t>(Byte())) / 16.0;
        const int exponent = static_cast<int>(Byte() % 32) - 16;
        return mantissa * std::pow(10.0, exponent);
      }
    }
  }

  Vector2 Vec2() {
    const double x = Double();
    return {x, Double()};
  }

 private:
  const std::uint8_t* data_;
  std::size_t size_;
  std::size_t pos_ = 0;
};

// An invariant does not hold: abort, so that libFuzzer records the input as a crash.
[[noreturn]] inline void Violation(const std::string& what) {
  std::fprintf(stderr, "fuzz invariant violated: %s\n", what.c_str());
  std::abort();
}

}  // namespace deif::fuzz
