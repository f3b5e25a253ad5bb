// What a process counts (<process>.counters.json, docs/ARTEFACTS.md), carried across its
// restarts: a process started again with --append (in place, docs/RUNNING.md "Restarting in
// place", or by the launcher after a crash) adds its counts to those its earlier process
// wrote, so a restart loses none of them. A process writes its counters once a second while
// it runs and at its end, each time whole, so a process killed with -9 loses at most the
// last second of its counts.
#pragma once

#include <string>

#include <nlohmann/json.hpp>
#include <spdlog/logger.h>

namespace deif::dds {

// The counters the earlier process wrote to `path`: an empty object when there is no such
// file, and when it cannot be read as a JSON object (said on `log`; the counts start again).
nlohmann::json EarlierCounters(const std::string& path, spdlog::logger& log);

// `now` with the counts of `earlier` added: every integer at the top level of both, and every
// reason of `by_reason` in either. The rest is now's: `grace_factor` (the state at the end)
// and `delivery_ms` (percentiles, since the last start).
nlohmann::json AddEarlierCounters(const nlohmann::json& earlier, nlohmann::json now);

// How often a running process writes its counters [s].
constexpr double kCountersEveryS = 1.0;

// Writes `counters` to `path` whole: to a temporary file beside it, renamed over it, so that a
// process killed while it writes leaves the file it wrote before, never half of one. Says
// on `log` when it cannot, once per process (the run goes on).
void WriteCounters(const std::string& path, const nlohmann::json& counters, spdlog::logger& log);

}  // namespace deif::dds
