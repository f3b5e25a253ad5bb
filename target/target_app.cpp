#include "target/target_app.hpp"

#include <algorithm>
#include <chrono>
#include <thread>
#include <type_traits>

#include "target/conversions.hpp"

namespace deif::target {

TargetApp::TargetApp(const Config& config, TargetOptions options, std::shared_ptr<spdlog::logger> log)
    : config_(config),
      options_(std::move(options)),
      log_(std::move(log)),
      core_(config_),
      state_listener_(
          [this](const deif_msgs::AgentState& m, const dds::WriterKey& w) { inbox_.Push(StateEvent{m, w}); },
          [this](const dds::WriterKey& w, bool alive) { inbox_.Push(WriterEvent{w, alive}); }) {
  const NetworkConfig& network = config_.network;
  participant_ = std::make_unique<dds::DdsParticipant>(network.domain_id, network, "target");
  truth_writer_ = participant_->CreateWriter(dds::kTruthTopic, dds::TruthWriterQos());
  range_writer_ = participant_->CreateWriter(dds::kRangeTopic, dds::RangeWriterQos());
  participant_->CreateReader(dds::kAgentStateTopic, dds::AgentStateReaderQos(network), &state_listener_);
  log_->info("target up on domain {}", network.domain_id);
}

TargetApp::~TargetApp() { participant_.reset(); }

void TargetApp::stop() {
  stop_requested_.store(true);
  inbox_.Wake();
}

void TargetApp::Pump(dds::Clock::time_point deadline) {
  for (const Event& event : inbox_.WaitUntil(deadline)) {
    if (const auto* state = std::get_if<StateEvent>(&event)) {
      const AgentId id = state->msg.agent_id();
      if (state_writers_.OnSample(state->writer, id, dds::Clock::now())) {
        log_->info("agent {} seen (writer {})", id, dds::ToString(state->writer));
      }
      latest_[id] = state->msg;  // arrival order: a restarted agent's step 0 replaces the old
    } else if (const auto* change = std::get_if<WriterEvent>(&event)) {
      const auto id = state_writers_.OnWriterChanged(change->writer, change->alive);
      if (id && !change->alive) log_->warn("agent {} lost (liveliness): no longer waited for", *id);
      if (id && change->alive) log_->info("agent {} alive", *id);
    }
  }
}

std::set<AgentId> TargetApp::AliveAgents() const {
  std::set<AgentId> agents;
  for (AgentId id : state_writers_.AliveIds()) {
    if (latest_.count(id) > 0) agents.insert(id);
  }
  return agents;
}

std::optional<StepIndex> TargetApp::WaitForAgents() {
  const auto start = dds::Clock::now();
  const auto deadline = start + dds::ToDuration(config_.network.start_timeout_s);
  // After a restart, running agents (some possibly dead) are discovered over a few
  // seconds (measured: up to ~3 s with the default transports): wait at least 3 participant
  // leases, and until no new agent appeared for one lease.
  const double lease_s = config_.network.participant_lease_s;
  const auto discovery = start + dds::ToDuration(3.0 * lease_s);
  const auto quiet = dds::ToDuration(lease_s);
  const auto expected = static_cast<std::size_t>(config_.agents.count);
  std::size_t seen = 0;
  auto last_new = start;
  while (!stop_requested_) {
    const auto now = dds::Clock::now();
    const auto agents = AliveAgents();
    if (agents.size() > seen) last_new = now;
    seen = agents.size();
    StepIndex max_step = 0;
    for (AgentId id : agents) max_step = std::max<StepIndex>(max_step, latest_.at(id).step());
    const bool resuming = max_step > 0 || options_.start_step.has_value();
    const bool ready = agents.size() >= expected || (resuming && now >= discovery && now - last_new >= quiet && !agents.empty()) ||
                       (now >= deadline && !agents.empty());
    if (ready) {
      std::string who;
      for (AgentId id : agents) who += " " + std::to_string(id);
      const StepIndex first = options_.start_step ? *options_.start_step : max_step + 1;
      log_->info("{} of {} agents present:{}; starting at step {}", agents.size(), expected, who, first);
      return first;
    }
    if (now >= deadline + dds::ToDuration(config_.network.start_timeout_s)) {
      log_->error("no agent appeared within {} s", 2 * config_.network.start_timeout_s);
      return std::nullopt;
    }
    Pump(now + std::chrono::milliseconds(100));
  }
  return std::nullopt;
}

void TargetApp::OpenArtefacts(bool append) {
  if (options_.out_dir.empty()) {
    log_->warn("no --out directory: target.csv and ranges.csv are not written");
    return;
  }
  const std::string target_path = options_.out_dir + "/target.csv";
  const std::string ranges_path = options_.out_dir + "/ranges.csv";
  if (append) {
    target_append_ = std::make_unique<CsvAppender>(target_path, kTargetCsvHeader);
    ranges_append_ = std::make_unique<CsvAppender>(ranges_path, kRangesCsvHeader);
  } else {
    target_csv_.emplace(target_path);
    ranges_csv_.emplace(ranges_path);
  }
}

int TargetApp::run() {
  const auto first = WaitForAgents();
  if (!first) return stop_requested_ ? kExitOk : kExitRuntimeError;
  const StepIndex first_step = std::max<StepIndex>(1, *first);
  const bool resuming = first_step > 1;
  OpenArtefacts(resuming);

  // The truth must be asked in increasing order (a random-walk offset accumulates).
  for (StepIndex k = 1; k < first_step; ++k) core_.TruthAt(k);

  const bool real_time = config_.scenario.mode == StepMode::kRealTime;
  const auto period = dds::ToDuration(config_.scenario.period_s);
  auto next_tick = dds::Clock::now();
  const auto run_start = dds::Clock::now();
  bool warned_empty = false;
  StepIndex k = first_step;
  for (; k <= config_.scenario.steps && !stop_requested_; ++k) {
    // Apply what arrived meanwhile (liveliness changes first of all).
    Pump(dds::Clock::now());
    const auto agents = AliveAgents();
    if (agents.empty() && !warned_empty) log_->warn("step {}: no agent alive", k);
    warned_empty = agents.empty();
    PublishStep(k, agents);
    if (real_time) {
      next_tick += period;
      while (!stop_requested_ && dds::Clock::now() < next_tick) Pump(next_tick);
    } else {
      WaitForStates(k, agents);
    }
  }
  const double elapsed_s = std::chrono::duration<double>(dds::Clock::now() - run_start).count();
  const StepIndex stepped = k - first_step;
  log_->info("{} after step {}: {} steps in {:.3f} s ({:.1f} steps/s)",
             stop_requested_ ? "stopped" : "run over", k - 1, stepped, elapsed_s,
             elapsed_s > 0 ? static_cast<double>(stepped) / elapsed_s : 0.0);
  if (!stop_requested_) PublishEndOfRun();
  return kExitOk;
}

void TargetApp::PublishStep(StepIndex k, const std::set<AgentId>& agents) {
  TargetRow truth{k, core_.TimeAt(k), core_.TruthAt(k)};
  deif_msgs::Truth truth_msg = ToIdl(truth);
  truth_writer_->write(&truth_msg);
  if (target_csv_) target_csv_->Write(truth);
  if (target_append_) target_append_->WriteLine(FormatRow(truth));

  for (AgentId id : agents) {
    const deif_msgs::AgentState& state = latest_.at(id);
    if (state.step() != k - 1) {
      log_->debug("step {}: agent {}'s latest state is for step {}", k, id, state.step());
    }
    RangeRow row;
    row.step = k;
    row.agent_id = id;
    row.p_sensor = ToEigenPosition(state);  // the agent's latest published position
    row.range_m = core_.NoisyRange(k, id, truth.p_true, row.p_sensor);
    row.variance_m2 = config_.filter.range_variance_m2;
    deif_msgs::Range range_msg = ToIdl(row);
    range_writer_->write(&range_msg);
    if (ranges_csv_) ranges_csv_->Write(row);
    if (ranges_append_) ranges_append_->WriteLine(FormatRow(row));
  }
}

void TargetApp::WaitForStates(StepIndex k, const std::set<AgentId>& agents) {
  const auto deadline = dds::Clock::now() + dds::ToDuration(config_.network.step_timeout_s);
  auto pending = [&] {
    std::set<AgentId> out;
    const auto alive = state_writers_.AliveIds();  // a lost agent is not waited for
    for (AgentId id : agents) {
      if (alive.count(id) > 0 && latest_.at(id).step() < k) out.insert(id);
    }
    return out;
  };
  while (!stop_requested_) {
    const auto missing = pending();
    if (missing.empty()) return;
    if (dds::Clock::now() >= deadline) {
      std::string who;
      for (AgentId id : missing) who += " " + std::to_string(id);
      log_->warn("step {}: timed out waiting for the states of agents{}", k, who);
      return;
    }
    Pump(deadline);
  }
}

void TargetApp::PublishEndOfRun() {
  deif_msgs::Truth end;
  end.step(dds::kEndOfRunStep);
  for (int i = 0; i < 5; ++i) {
    truth_writer_->write(&end);
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  truth_writer_->wait_for_acknowledgments(eprosima::fastrtps::Duration_t(1, 0));
  log_->info("published the end of the run");
}

}  // namespace deif::target
