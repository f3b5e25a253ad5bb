// The skeleton every DDS executable shares (Fast DDS's examples keep one Application
// interface and one main): the command-line options, the config, the logger, SIGINT/SIGTERM
// wired to Stop(), and errors mapped to one line and an exit code (docs/RUNNING.md).
#pragma once

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <exception>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <spdlog/logger.h>

#include "common/config/config.hpp"
#include "common/protocol/agent_protocol.hpp"

// CLI11 is included only where options are declared or parsed (the mains and
// application.cpp): it is the costliest header of the build.
namespace CLI {
class App;
}  // namespace CLI

namespace deif::dds {

// Options and values a process restarted in place is given instead of its first ones.
using RestartOptions = std::vector<std::pair<std::string, std::string>>;

// An executable's application object: RAII over its DDS entities.
class Application {
 public:
  virtual ~Application() = default;
  // Runs until done or Stop(); returns the exit code.
  virtual int Run() = 0;
  // Thread-safe: makes Run() return soon.
  virtual void Stop() = 0;
  // After Run(), unless it starts again in place: true when the run is over for this
  // process's part (it ended with the run, or gave up on it; not stopped, not refused) and the
  // node has been abandoned (Node::Abandon): the process then ends at once with Run()'s code,
  // without deleting its participant (docs/FASTDDS_NOTES.md, "Leaving at the end of a run").
  // Otherwise RunMain deletes the participant (docs/FASTDDS_NOTES.md, "Leaving while the run
  // goes on").
  virtual bool LeaveQuietly() { return false; }
  // After Run(): true when the process must start again in place because it can no longer
  // hear the network (Node::ReceiveStuck) or its discovery stopped short: RunMain then
  // deletes its participant and execs the same command with --append (the same pid, a new
  // participant), which rejoins the run like a restarted process (docs/RUNNING.md,
  // "Restarting in place").
  virtual bool RestartInPlace() const { return false; }
  // Options whose value that restart changes (each replaces the option given before, if
  // any), e.g. the target's step so far: {{"--start-step", "216"}}.
  virtual RestartOptions RestartOptionsOf() const { return {}; }
};

// The options every DDS executable takes.
struct ProcessOptions {
  std::string config_path;
  std::vector<std::string> overrides;  // --set dotted.key=value
  std::string log_dir;
  std::string out_dir;
  std::string domain;                  // text, checked like the config key
  std::string seed;
  std::string run_name;                // --run
  bool append = false;                 // append to existing CSVs (a restarted process)
};

struct ProcessContext {
  Config config;
  ProcessOptions options;
  std::string run_name;  // the effective run name
  std::shared_ptr<spdlog::logger> log;
};

// The last step of the CSV `file_name` in --out that a process started with --append appends
// to, read with `read` (0: not --append, no --out, no such file or no rows). A process never
// writes a row at or before it (docs/RUNNING.md). If the file cannot be read, it logs so with
// what it does instead (`otherwise`) and returns 0.
template <typename Row>
StepIndex LastStepAppendedTo(const ProcessContext& context, const std::string& file_name,
                             std::vector<Row> (*read)(const std::string&), const char* otherwise) {
  if (!context.options.append || context.options.out_dir.empty()) return 0;
  const std::string path = context.options.out_dir + "/" + file_name;
  try {
    StepIndex last = 0;
    for (const Row& row : read(path)) last = std::max(last, row.step);  // no file: no rows
    return last;
  } catch (const std::exception& e) {
    context.log->warn("--append: cannot read the steps of {} ({}); {}", path, e.what(), otherwise);
    return 0;
  }
}

struct ProcessSpec {
  const char* program;      // "deif_agent"
  const char* description;
  // Adds the executable's own options.
  std::function<void(CLI::App&)> add_options;
  // The logger's (and log file's) name, e.g. "agent-3"; also the DDS participant's name,
  // by which it finds its security files (docs/SECURITY.md), unless identity_name is set.
  std::function<std::string()> logger_name;
  // The name of its security identity where it differs from logger_name ("observer-1").
  std::function<std::string()> identity_name;
  // Checks the executable's own options against the config; throws ConfigError.
  std::function<void(const Config&)> check;
  // Makes the application (after every check passed).
  std::function<std::unique_ptr<Application>(ProcessContext&)> make;
};

// The whole main(): parses, checks everything before starting anything (a bad option or
// config prints `<program>: error: <file>:<line>: key '<key>': <reason>` and returns 2),
// runs, and maps exceptions to exit code 1 with one line.
int RunMain(int argc, char** argv, const ProcessSpec& spec);

// The environment variable that counts a process's restarts in place (RestartInPlace), and
// their number so far in this process (0 in one started afresh).
constexpr const char* kRestartsVariable = "DEIF_RESTARTS_IN_PLACE";
constexpr int kMaxRestartsInPlace = 3;  // then a process that is stuck again ends with code 1
int RestartsInPlace();
// DEIF_FAULT_DEAF=STEP:WHO[,STEP:WHO...] (WHO: an agent id, or "target"): the step from which
// the first process of `who` acts as if its receive were stuck, so that tests can run the
// restart in place on demand (docs/RUNNING.md, "Restarting in place"); 0 when not asked.
StepIndex FaultDeafStep(const std::string& who);
// DEIF_FAULT_THROW=STEP:WHO[,...], the same way: the step from which the first process of
// `who` ends a thread of its own with the exception Fast DDS throws when an interprocess lock
// times out (ThrowInAThreadForTest), so that tests can see it start again in place
// (docs/FASTDDS_NOTES.md, "An exception that ends a thread"); 0 when not asked.
StepIndex FaultThrowStep(const std::string& who);
void ThrowInAThreadForTest();
// DEIF_FAULT_CRASH=STEP:WHO[,...], the same way: the step from which the first process of
// `who` crashes (SIGSEGV in a thread of its own, CrashInAThreadForTest; the target in the
// middle of sending that step's ranges, after the first), so that tests can
// see it start again in place (docs/RUNNING.md, "A crash"); 0 when not asked.
StepIndex FaultCrashStep(const std::string& who);
// With `wait`, the calling thread waits for the crash: nothing it would do next happens.
void CrashInAThreadForTest(bool wait = false);
// DEIF_FAULT_READER_LOOP=STEP:WHO[,...], the same way: the step from which the first process
// of `who` is caught, in its main loop, as in Fast DDS's loop over a change a keyed reader's
// history lost track of (LoopOverALostChangeForTest), so that tests can see it start again
// in place (docs/FASTDDS_NOTES.md, "A reader that hands out one sample for ever"); 0 when
// not asked.
StepIndex FaultReaderLoopStep(const std::string& who);
// How Fast DDS's (boost's) exception of a timed-out interprocess lock begins.
constexpr const char* kLockTimeout = "Interprocess mutex timeout when locking";
// For a process that must start again with a new participant (`why`): logs why, and whether
// it may start again in place (true) or already did kMaxRestartsInPlace times (false). `when`
// says where its run stands, e.g. "after step 50".
bool MayRestartInPlace(spdlog::logger& log, const std::string& why, const std::string& when);
// Why a process whose shared-memory receive is stuck (Node::ReceiveStuck) starts again.
constexpr const char* kReceiveStuck =
    "this process hears nothing more: a shared-memory receive thread of Fast DDS is stuck on a message of "
    "a dead peer (docs/FASTDDS_NOTES.md)";

class Node;  // dds/node.hpp

// Whether `node` lost a shared-memory port to a peer (Node::PortsLost: a peer replaced it
// under this process, which no longer hears whoever opens it since) and may start again in
// place for it (logged, as MayRestartInPlace). When it may not, `watching` becomes false and
// the process goes on as it is. `when` as for MayRestartInPlace.
bool RestartForLostPorts(Node& node, spdlog::logger& log, const std::string& when, bool& watching);

// Logs each reader that `node` made anew since the last call (Node::ReadersMadeAnew), once
// per call of it.
void LogReadersMadeAnew(Node& node, spdlog::logger& log);

// A protocol's log line, at its level, through the process logger.
void LogAt(spdlog::logger& log, protocol::LogLevel level, const std::string& text);
// The actions both protocols produce: a log line; the end of the process (its exit code is
// kept for Run() to return).
void Carry(const protocol::Log& action, spdlog::logger& log);
void Carry(const protocol::Finish& action, spdlog::logger& log, std::optional<int>& exit_code);

// When an application's event loop should wake: at the protocol's next deadline, and at
// least every max_wait_s (to notice a stop request).
std::chrono::steady_clock::time_point WakeBy(std::optional<double> deadline_s, double max_wait_s);

// The run name when --run is not given: derived from the effective config, so processes
// started by hand with the same config (and seed) find each other and no others.
std::string DefaultRunName(const Config& config);

// A run name is 1..64 characters of [A-Za-z0-9._-]; throws ConfigError otherwise.
void CheckRunName(const std::string& name);

}  // namespace deif::dds
