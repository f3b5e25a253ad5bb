// How long samples of one kind took from their writer to the application that took them
// (docs/ARTEFACTS.md, "Delivery delays"): counted in fixed bins, so a run of any length
// keeps the same few hundred bytes per kind.
#pragma once

#include <array>
#include <cstdint>

namespace deif {

class DelayHistogram {
 public:
  // Bins of 1/20 of a decade (12 % wide) from 10 us to 100 s; beyond either end a delay
  // counts in the first or last bin. A negative delay (the clocks of two hosts) counts as 0.
  static constexpr int kBinsPerDecade = 20;
  static constexpr double kLowest_s = 1e-5;
  static constexpr int kBins = 7 * kBinsPerDecade;

  void Add(double delay_s);
  std::int64_t count() const { return count_; }
  double max_s() const { return max_s_; }
  // The delay below which a fraction q (0..1) of the samples fell: the upper edge of the bin
  // that holds it, so never below the true quantile and at most 12 % above it; 0 when empty.
  double Quantile(double q) const;

 private:
  std::array<std::int64_t, kBins> bins_{};
  std::int64_t count_ = 0;
  double max_s_ = 0.0;
};

}  // namespace deif
