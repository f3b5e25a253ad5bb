#include "target/target_node.hpp"

#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <set>
#include <string>
#include <type_traits>
#include <variant>

#include <nlohmann/json.hpp>

namespace deif::target {

namespace {

constexpr double kMaxWaitS = 0.5;
// How often it looks for agents' processes that ended (docs/PROTOCOL.md, "A process that
// ended"); the loop wakes for it too, once the run has started.
constexpr double kEndedCheckS = 0.1;

// A step done again has the rows on file (in lock-step the same rows: the truth and the
// noise are functions of the seed, the step and the position the agent published); only the
// agents the previous process did not measure get a row (TargetNode::Execute).
RowsOnFile ReadRowsOnFile(const dds::ProcessContext& context, const TargetOptions& options) {
  RowsOnFile out;
  if (context.options.out_dir.empty() || !(options.start_step || context.options.append)) return out;
  const std::filesystem::path dir(context.options.out_dir);
  const std::string truth_path = (dir / kTargetCsvSchema.file_name).string();
  const std::string ranges_path = (dir / kRangesCsvSchema.file_name).string();
  try {
    for (const TargetRow& row : ReadTargetCsv(truth_path)) out.truth_through = std::max(out.truth_through, row.step);
    for (const RangeRow& row : ReadRangesCsv(ranges_path)) {
      if (row.step > out.ranges_through) {
        out.ranges_through = row.step;
        out.ranges_at_last.clear();
      }
      if (row.step == out.ranges_through) out.ranges_at_last.insert(row.agent_id);
    }
  } catch (const std::exception& e) {
    context.log->warn("cannot read the rows of {} and {} ({}); resuming after the agents' newest step, "
                      "and a step done again may be written twice",
                      truth_path, ranges_path, e.what());
    return {};
  }
  return out;
}

protocol::TargetProtocol::Options ProtocolOptions(const dds::ProcessContext& context,
                                                  const TargetOptions& options, const RowsOnFile& on_file) {
  protocol::TargetProtocol::Options out;
  out.run = protocol::RunTokenOf(context.run_name);
  out.start_step = options.start_step;
  // A target that starts again with --append (in place after a crash, or by hand) never goes
  // back before the last step its target.csv holds: that step is a floor, as --start-step
  // is. It is the step in flight when the previous process ended, whose ranges may have
  // reached only some agents: the new process does it again if the agents have not finished
  // it, without writing its rows twice (TargetNode::Execute).
  if (context.options.append && on_file.truth_through > 0) {
    const StepIndex floor = std::min(on_file.truth_through, context.config.scenario.steps);
    out.start_step = std::max(out.start_step.value_or(0), floor);
  }
  out.hold_for_faults = options.hold_for_faults;
  out.start_grace_s = dds::EffectiveTimings(context.config).peer_grace_s;
  return out;
}

}  // namespace

TargetNode::TargetNode(dds::ProcessContext& context, TargetOptions options)
    : context_(context),
      config_(context.config),
      options_(options),
      on_file_(ReadRowsOnFile(context, options)),
      node_(context.config, "target", context.run_name),
      protocol_(context.config, ProtocolOptions(context, options, on_file_)),
      discovery_watch_(dds::DiscoveryPatienceS(context.config, dds::RestartsInPlace())),
      forgetting_(dds::EffectiveTimings(context.config)) {
  if (context_.options.append && !context_.options.out_dir.empty()) {
    earlier_counters_ = dds::EarlierCounters(CountersPath(), *context_.log);
  }
  node_.AddWriter(dds::Topic::kTruth);
  node_.AddReader({dds::Topic::kAgentState, {}});
  // A reader of ranges for id 0, which nobody writes: before this target has a range writer
  // of its own, it matches only another target's (see AnotherTargetInThisRun).
  node_.AddReader({dds::Topic::kRange, 0});
  if (node_.AuthenticationRestarts() > 0) {
    context_.log->warn("authentication with a peer stalled at start; participant created anew {} "
                       "time(s) (docs/SECURITY.md, \"Start-up\")",
                       node_.AuthenticationRestarts());
  }
  context_.log->info("target up: run '{}', domain {}", context_.run_name, config_.network.domain_id);
}

TargetNode::~TargetNode() {
  if (control_thread_.joinable()) control_thread_.detach();  // blocked in a read of stdin
}

void TargetNode::Stop() {
  stop_requested_.store(true);
  node_.Wake();
}

bool TargetNode::AnotherTargetInThisRun() {
  // Another target is a range writer of this run that is *alive*, not merely matched: a
  // Discovery Server goes on announcing a killed target's endpoints until its participant
  // lease ends (5 s by default), and a target restarted meanwhile matched that dead writer
  // and refused to start (docs/PROTOCOL.md, "The target", "One per run"). A live writer
  // asserts its liveliness every lease; a dead one is reported lost a lease after it
  // matched, if it was reported alive at all. So the window outlasts a lease and its grace.
  const auto& net = config_.network;
  const double wait_s = std::max({1.0, 2.0 * net.participant_announcement_s,
                                  1.5 * net.liveliness_lease_s + net.liveliness_grace_s});
  const auto deadline = dds::Clock::now() + std::chrono::duration_cast<dds::Clock::duration>(
                                                std::chrono::duration<double>(wait_s));
  std::set<protocol::SenderKey> alive;
  while (!stop_requested_ && dds::Clock::now() < deadline) {
    for (dds::Event& event : node_.Wait(std::min(deadline, dds::Clock::now() + std::chrono::milliseconds(100)))) {
      if (const auto* change = std::get_if<dds::LivelinessChange>(&event)) {
        if (change->topic == dds::Topic::kRange) {
          if (change->alive) {
            alive.insert(change->writer);
          } else {
            alive.erase(change->writer);
          }
        }
      } else if (const auto* range = std::get_if<dds::Received<protocol::RangeMsg>>(&event)) {
        alive.insert(range->from);  // it wrote: it lives (until reported lost)
      }
      early_events_.push_back(std::move(event));
    }
  }
  if (!alive.empty() && node_.MatchedWriters(dds::Topic::kRange) > 0) {
    context_.log->error("run '{}' already has a target on domain {}", context_.run_name,
                        config_.network.domain_id);
    return true;
  }
  return false;
}

void TargetNode::ReadControl() {
  std::string line;
  while (std::getline(std::cin, line)) {
    unsigned long long step = 0;
    if (std::sscanf(line.c_str(), "go %llu", &step) == 1) {
      {
        std::lock_guard<std::mutex> lock(control_mutex_);
        go_steps_.push_back(static_cast<StepIndex>(step));
      }
      node_.Wake();
    }
  }
}

int TargetNode::Run() {
  if (AnotherTargetInThisRun()) return protocol::kExitDuplicate;
  if (stop_requested_) return protocol::kExitOk;
  node_.AddWriter(dds::Topic::kRange);
  node_.StartLiveliness();
  if (!context_.options.out_dir.empty()) {
    // A restarted target (--start-step or --append) appends to the run's files.
    const CsvMode mode = options_.start_step || context_.options.append ? CsvMode::kAppend
                                                                       : CsvMode::kTruncate;
    const std::filesystem::path dir(context_.options.out_dir);
    target_csv_.emplace((dir / kTargetCsvSchema.file_name).string(), mode);
    ranges_csv_.emplace((dir / kRangesCsvSchema.file_name).string(), mode);
  } else {
    context_.log->warn("no --out folder: target.csv and ranges.csv are not written");
  }
  if (options_.hold_for_faults) control_thread_ = std::thread([this] { ReadControl(); });

  const auto started = dds::Clock::now();
  protocol_.Start(dds::ToSeconds(started));
  for (const dds::Event& event : early_events_) Dispatch(event, dds::ToSeconds(started));
  early_events_.clear();
  Execute(protocol_.TakeActions());
  while (!stop_requested_ && !protocol_.finished()) {
    const std::vector<dds::Event> events =
        node_.Wait(dds::WakeBy(protocol_.NextDeadline(), protocol_.started() ? kEndedCheckS : kMaxWaitS));
    const double now_s = dds::ToSeconds(dds::Clock::now());
    if (protocol_.started()) delivery_.Record(events);  // from the first step on (as the agents)
    for (const dds::Event& event : events) {
      forgetting_.Note(event, now_s);
      Dispatch(event, now_s);
    }
    dds::LogReadersMadeAnew(node_, *context_.log);
    std::deque<StepIndex> go;
    {
      std::lock_guard<std::mutex> lock(control_mutex_);
      go.swap(go_steps_);
    }
    for (StepIndex step : go) protocol_.OnGo(step, now_s);
    for (const protocol::SenderKey& ended : node_.EndedAgents(kEndedCheckS)) protocol_.OnProcessEnded(ended, now_s);
    if (!protocol_.started()) protocol_.OnRangeReaders(node_.MatchedReaderKeys(dds::Topic::kRange));
    protocol_.OnTimer(now_s);
    Execute(protocol_.TakeActions());
    if (now_s >= counters_due_s_) {  // a kill -9 loses at most the last second of them
      WriteCounters();
      counters_due_s_ = now_s + dds::kCountersEveryS;
    }
    // The run is over: nothing to start again for. The agents leave at its end, and a receive
    // thread may then be caught on a message of one that left; the target started again in
    // place for it, waited for agents that had finished, and ended with an error.
    if (protocol_.finished()) break;
    if ((!protocol_.started() && DiscoveryStoppedShort(now_s)) || ForgottenByTheServer(now_s)) {
      WriteCounters();
      return protocol::kExitRuntimeError;  // the exit code if it cannot start again
    }
    if (dds::Node::ReceiveStuck() || DeafForTest()) {
      // Fast DDS 2.9.1 cannot recover the port (docs/FASTDDS_NOTES.md, "A receive loop stuck
      // on a dead writer's segment"); a new participant can. The new process resumes after
      // the agents' newest step, as a restarted target does (docs/PROTOCOL.md).
      WriteCounters();
      restart_in_place_ = dds::MayRestartInPlace(*context_.log, dds::kReceiveStuck,
                                                 "at step " + std::to_string(protocol_.current_step()));
      return protocol::kExitRuntimeError;  // the exit code when it does not start again
    }
    if (dds::RestartForLostPorts(node_, *context_.log, "at step " + std::to_string(protocol_.current_step()),
                                 watching_ports_)) {
      WriteCounters();
      restart_in_place_ = true;  // resumes after the agents' newest step, as above
      return protocol::kExitRuntimeError;
    }
  }
  const double elapsed_s = std::chrono::duration<double>(dds::Clock::now() - started).count();
  context_.log->info("{} at step {} after {:.3f} s; liveliness lapses forgiven {}",
                     stop_requested_ ? "stopped" : "done", protocol_.current_step(), elapsed_s,
                     protocol_.lapses_forgiven());
  for (const auto& [reason, count] : protocol_.rejected_by_reason()) {
    context_.log->info("  {}: {}", reason, count);
  }
  if (const std::string delays = delivery_.Summary(); !delays.empty()) {
    context_.log->info("delivery delays p50 / p99 [ms]: {}", delays);
  }
  WriteCounters();
  if (!stop_requested_) node_.WaitForAcknowledgments(1.0);  // the last ranges reach the agents
  return stop_requested_ ? protocol::kExitOk : exit_code_.value_or(protocol::kExitOk);
}

dds::RestartOptions TargetNode::RestartOptionsOf() const {
  // The step it was at: the new process does it again unless the agents finished it (its
  // ranges may not have reached them all), without writing its rows twice (ReadRowsOnFile).
  // While it waits for the agents (step 0), the step it was given.
  const StepIndex current = protocol_.current_step();
  const StepIndex floor = std::max(options_.start_step.value_or(0), current);
  if (floor < 1) return {};
  return {{"--start-step", std::to_string(floor)}};
}

std::string TargetNode::CountersPath() const {
  return (std::filesystem::path(context_.options.out_dir) / "target.counters.json").string();
}

void TargetNode::WriteCounters() const {
  if (context_.options.out_dir.empty()) return;
  std::int64_t rejected = 0;
  for (const auto& [reason, count] : protocol_.rejected_by_reason()) rejected += count;
  const nlohmann::json counters = {{"rejected", rejected},
                                   {"lapses_forgiven", protocol_.lapses_forgiven()},
                                   {"losses_undone", protocol_.losses_undone()},
                                   {"grace_factor", protocol_.grace_factor()},
                                   {"by_reason", protocol_.rejected_by_reason()},
                                   {"delivery_ms", delivery_.ToJson()}};
  dds::WriteCounters(CountersPath(), dds::AddEarlierCounters(earlier_counters_, counters), *context_.log);
}

bool TargetNode::DiscoveryStoppedShort(double now_s) {
  if (node_.Secure() || !discovery_watch_.Due(now_s)) return false;
  const auto alive = static_cast<int>(protocol_.AliveAgents().size());
  const std::set<AgentId> unreached = protocol_.Unreached();
  if (!discovery_watch_.Stalled(alive, alive - static_cast<int>(unreached.size()),
                                node_.EndpointsHeard(), now_s)) {
    return false;
  }
  std::string who;
  for (AgentId id : unreached) who += " " + std::to_string(id);
  const std::string why =
      "endpoint discovery stopped short: the readers of ranges of agents" + who +
      " (present: their states arrive) are unknown to this target's writer, unchanged for " +
      std::to_string(static_cast<int>(discovery_watch_.patience_s())) +
      " s (docs/FASTDDS_NOTES.md, \"Endpoint discovery that stops short\")";
  if (dds::MayRestartInPlace(*context_.log, why, "before step 1")) {
    restart_in_place_ = true;
    return true;
  }
  discovery_watch_.GiveUp();
  return false;
}

bool TargetNode::ForgottenByTheServer(double now_s) {
  // The server dropped the target and told the agents so (docs/FASTDDS_NOTES.md, "Forgotten
  // by the server"). The new process resumes after the agents' newest step.
  if (config_.network.discovery != DiscoveryKind::kServer || !protocol_.started()) return false;
  const std::optional<std::string> why =
      forgetting_.Forgotten(node_, [this] { return !node_.AgentsUp().empty(); }, "no agent", now_s);
  if (!why) return false;
  if (dds::MayRestartInPlace(*context_.log, *why, "at step " + std::to_string(protocol_.current_step()))) {
    restart_in_place_ = true;
    return true;
  }
  forgetting_.GiveUp();  // said once; it goes on as it is
  return false;
}

bool TargetNode::DeafForTest() const {
  static const StepIndex at_step = dds::FaultDeafStep("target");
  if (at_step > config_.scenario.steps) return protocol_.finished();  // once the run is over
  return at_step > 0 && protocol_.current_step() >= at_step;
}

bool TargetNode::CrashForTest(StepIndex step) {
  static const StepIndex at_step = dds::FaultCrashStep("target");
  if (crashed_for_test_ || at_step == 0 || step < at_step) return false;
  crashed_for_test_ = true;
  return true;
}

void TargetNode::Dispatch(const dds::Event& event, double now_s) {
  if (const auto* state = std::get_if<dds::Received<protocol::StateMsg>>(&event)) {
    // With security, only agent J's own writer may speak for J (docs/SECURITY.md).
    if (node_.Secure() && node_.AuthorizedAgent(state->from) != state->msg.agent_id) {
      protocol_.OnUnauthorised(state->msg.agent_id, state->from);
      return;
    }
    protocol_.OnState(state->msg, state->from, now_s);
  } else if (const auto* change = std::get_if<dds::LivelinessChange>(&event)) {
    if (change->topic == dds::Topic::kAgentState) {
      protocol_.OnWriterLiveliness(change->writer, change->alive, now_s);
    }
  }
}

void TargetNode::Execute(std::vector<protocol::TargetAction> actions) {
  for (protocol::TargetAction& action : actions) {
    std::visit(
        [this](auto& a) {
          using A = std::decay_t<decltype(a)>;
          namespace act = protocol::target_action;
          if constexpr (std::is_same_v<A, act::PublishRange>) {
            node_.Write(a.msg);
            // DEIF_FAULT_CRASH: at the worst moment, a step's ranges sent to some agents only.
            if (CrashForTest(a.msg.step)) dds::CrashInAThreadForTest(/*wait=*/true);
          } else if constexpr (std::is_same_v<A, act::PublishTruth>) {
            node_.Write(a.msg);
          } else if constexpr (std::is_same_v<A, act::WriteTruthRow>) {
            if (target_csv_ && a.row.step > on_file_.truth_through) target_csv_->Write(a.row);
          } else if constexpr (std::is_same_v<A, act::WriteRangeRow>) {
            const bool on_file = a.row.step < on_file_.ranges_through ||
                                 (a.row.step == on_file_.ranges_through && on_file_.ranges_at_last.count(a.row.agent_id) > 0);
            if (ranges_csv_ && !on_file) ranges_csv_->Write(a.row);
          } else if constexpr (std::is_same_v<A, act::Hold>) {
            std::printf("hold %lld %s\n", static_cast<long long>(a.step), a.faults.c_str());
            std::fflush(stdout);
          } else if constexpr (std::is_same_v<A, protocol::Log>) {
            dds::Carry(a, *context_.log);
          } else if constexpr (std::is_same_v<A, protocol::Finish>) {
            dds::Carry(a, *context_.log, exit_code_);
          }
        },
        action);
  }
}

bool TargetNode::LeaveQuietly() {
  // The end of the run: every process of the run leaves at about the same time
  // (dds::Node::Abandon). A process that gives up, is stopped, or never took part (another
  // process has its place) leaves while others on the domain go on, and says goodbye
  // (docs/FASTDDS_NOTES.md, "Leaving while the run goes on").
  if (stop_requested_ || !protocol_.finished() || exit_code_.value_or(protocol::kExitOk) != protocol::kExitOk) {
    return false;
  }
  node_.Abandon();
  return true;
}

}  // namespace deif::target
