// How long samples took from their writer to this process's application, by kind
// (docs/ARTEFACTS.md, "Delivery delays"): what a process reports in its counters.json and
// its last log line.
#pragma once

#include <map>
#include <string>
#include <vector>

#include <nlohmann/json_fwd.hpp>

#include "common/artefacts/delay_histogram.hpp"
#include "dds/node.hpp"

namespace deif::dds {

class DeliveryDelays {
 public:
  // Each received sample of `events`, against the system clock now: "range", "contribution",
  // "relay_up", "relay_down", "state", "truth".
  void Record(const std::vector<Event>& events);
  // {kind: {count, p50, p90, p99, max}}, the delays in milliseconds.
  nlohmann::json ToJson() const;
  // "range 4.0 / 8.9, relay_down 7.9 / 22.1": p50 / p99 in milliseconds; "" when none.
  std::string Summary() const;

 private:
  std::map<std::string, DelayHistogram> kinds_;
};

}  // namespace deif::dds
