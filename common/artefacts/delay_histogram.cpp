#include "common/artefacts/delay_histogram.hpp"

#include <algorithm>
#include <cmath>

namespace deif {

void DelayHistogram::Add(double delay_s) {
  if (!(delay_s > 0.0)) delay_s = 0.0;  // negative, or NaN
  int bin = 0;
  if (delay_s > kLowest_s) {
    const double position = std::log10(delay_s / kLowest_s) * kBinsPerDecade;
    bin = std::min(kBins - 1, static_cast<int>(std::min(position, double{kBins})));
  }
  ++bins_[static_cast<std::size_t>(bin)];
  ++count_;
  max_s_ = std::max(max_s_, delay_s);
}

double DelayHistogram::Quantile(double q) const {
  if (count_ == 0) return 0.0;
  const double wanted = std::clamp(q, 0.0, 1.0) * static_cast<double>(count_);
  std::int64_t seen = 0;
  for (int bin = 0; bin < kBins; ++bin) {
    seen += bins_[static_cast<std::size_t>(bin)];
    if (static_cast<double>(seen) >= wanted && seen > 0) {
      const double upper = kLowest_s * std::pow(10.0, static_cast<double>(bin + 1) / kBinsPerDecade);
      return std::min(upper, max_s_);
    }
  }
  return max_s_;
}

}  // namespace deif
