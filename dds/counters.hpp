// What a process counts (<process>.counters.json, docs/ARTEFACTS.md), carried across its
// restarts: a process started again with --append (in place, docs/RUNNING.md "Restarting in
// place", or by the launcher after a crash) adds its counts to those its earlier process
// wrote, so a restart loses none of them.
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

}  // namespace deif::dds
