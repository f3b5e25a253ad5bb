#include "agent/agent_app.hpp"

#include <algorithm>
#include <deque>
#include <chrono>
#include <type_traits>

#include "agent/conversions.hpp"

namespace deif::agent {

namespace {
constexpr int kKeptPositionSteps = 16;  // per peer, enough for the fusion window
template <class> inline constexpr bool kAlwaysFalse = false;
}  // namespace

AgentApp::AgentApp(const Config& config, AgentOptions options, std::shared_ptr<spdlog::logger> log)
    : config_(config),
      options_(std::move(options)),
      log_(std::move(log)),
      core_(config_, options_.id),
      instance_token_(dds::RandomInstanceToken()),
      truth_listener_([this](const deif_msgs::Truth& m, const dds::WriterKey&) { inbox_.Push(TruthEvent{m}); },
                      nullptr),
      range_listener_(
          [this](const deif_msgs::Range& m, const dds::WriterKey&) {
            if (m.agent_id() == options_.id) inbox_.Push(RangeEvent{m});  // only our own ranges
          },
          nullptr),
      contribution_listener_(
          [this](const deif_msgs::Contribution& m, const dds::WriterKey& w) { inbox_.Push(ContributionEvent{m, w}); },
          [this](const dds::WriterKey& w, bool alive) {
            inbox_.Push(WriterEvent{WriterTopic::kContribution, w, alive});
          }),
      state_listener_(
          [this](const deif_msgs::AgentState& m, const dds::WriterKey& w) { inbox_.Push(StateEvent{m, w}); },
          [this](const dds::WriterKey& w, bool alive) {
            inbox_.Push(WriterEvent{WriterTopic::kAgentState, w, alive});
          }) {
  const NetworkConfig& network = config_.network;
  participant_ = std::make_unique<dds::DdsParticipant>(network.domain_id, network,
                                                       "agent-" + std::to_string(options_.id));
  contribution_writer_ =
      participant_->CreateWriter(dds::kContributionTopic, dds::ContributionWriterQos(network));
  state_writer_ = participant_->CreateWriter(dds::kAgentStateTopic, dds::AgentStateWriterQos(network));
  own_contribution_writer_ = dds::ToWriterKey(contribution_writer_->get_instance_handle());
  own_state_writer_ = dds::ToWriterKey(state_writer_->get_instance_handle());
  published_positions_.push_back(core_.position());  // the initial position
  participant_->CreateReader(dds::kTruthTopic, dds::TruthReaderQos(), &truth_listener_);
  participant_->CreateReader(dds::kRangeTopic, dds::RangeReaderQos(), &range_listener_);
  participant_->CreateReader(dds::kContributionTopic, dds::ContributionReaderQos(network),
                             &contribution_listener_);
  participant_->CreateReader(dds::kAgentStateTopic, dds::AgentStateReaderQos(network), &state_listener_);
  log_->info("agent {} up on domain {} (token {:016x})", options_.id, network.domain_id, instance_token_);
}

AgentApp::~AgentApp() {
  asserter_.reset();
  participant_.reset();  // deletes every entity while the listeners still exist
}

void AgentApp::stop() {
  stop_requested_.store(true);
  inbox_.Wake();
}

// ---------------------------------------------------------------------------------------
int AgentApp::run() {
  if (RefuseDuplicateId()) {
    log_->error("agent id {} is already live", options_.id);
    return kExitDuplicateId;
  }
  if (stop_requested_) return kExitOk;
  // Only now do our writers become alive to the peers (a refused duplicate never does):
  // renew both MANUAL_BY_TOPIC leases four times per lease, also while waiting.
  asserter_ = std::make_unique<dds::LivelinessAsserter>(
      std::vector<dds::fdds::DataWriter*>{contribution_writer_, state_writer_},
      config_.network.liveliness_lease_s / 4.0);
  if (!options_.out_dir.empty()) {
    csv_.emplace(options_.out_dir + "/" + AgentCsvName(options_.id));
  } else {
    log_->warn("no --out directory: {} is not written", AgentCsvName(options_.id));
  }

  AgentSnapshot initial = core_.Initial();
  initial.alive = static_cast<int>(Members().size());
  Publish(initial, /*write_csv=*/false);  // the CSV holds steps 1..steps, like the simulation
  log_->info("published the initial state; waiting for the target");

  while (!stop_requested_ && done_ < config_.scenario.steps) {
    auto next = WaitForNextStep();
    if (!next) break;
    const auto& [k, z] = *next;
    // After a SIGSTOP or a restart the target may be ahead. Adopt a live peer's estimate of
    // step k-1, so that our prediction, and so our contribution's linearisation point
    // (eqs 4.49-4.51), is the network's; without one, predict once per step missed (eqs
    // 4.45-4.46; no range, no contribution, no fusion, no motion), as the in-process
    // simulation does for an agent that takes no part in a step.
    if (k > done_ + 1) {
      // The peers' states of step k-1 were published before the target sent range k, but
      // after a SIGCONT they may reach us after it: give them up to a step timeout.
      std::optional<AgentId> peer = AdoptPeerEstimate(k - 1);
      const auto deadline =
          dds::Clock::now() + dds::ToDuration(config_.network.step_timeout_s);
      while (!peer && !stop_requested_ && Members().size() > 1 && dds::Clock::now() < deadline) {
        Pump(std::min(deadline, dds::Clock::now() + std::chrono::milliseconds(20)));
        peer = AdoptPeerEstimate(k - 1);
      }
      if (peer) {
        log_->warn("missed steps {}..{}: adopted agent {}'s estimate of step {}", done_ + 1,
                   k - 1, *peer, k - 1);
      } else {
        for (StepIndex missed = done_ + 1; missed < k; ++missed) {
          core_.BeginStep(missed, std::nullopt);
        }
        log_->warn("skipped steps {}..{} (prediction only)", done_ + 1, k - 1);
      }
    }
    DoStep(k, z);
  }

  if (stop_requested_) {
    log_->info("stopped at step {}", done_);
  } else {
    log_->info("run over after step {} (rejected {}, dropped {})", done_, rejected_, dropped_);
  }
  if (!stop_requested_) {
    // Let reliable peers receive our last samples before the writers go away (bounded: a
    // peer that died meanwhile never acknowledges).
    const auto ack_start = dds::Clock::now();
    const eprosima::fastrtps::Duration_t ack_wait(0, 500'000'000);
    const bool acked = contribution_writer_->wait_for_acknowledgments(ack_wait) == ReturnCode_t::RETCODE_OK &&
                       state_writer_->wait_for_acknowledgments(ack_wait) == ReturnCode_t::RETCODE_OK;
    log_->info("last samples {}acknowledged after {:.3f} s", acked ? "" : "not all ",
                std::chrono::duration<double>(dds::Clock::now() - ack_start).count());
  }
  return kExitOk;
}

bool AgentApp::RefuseDuplicateId() {
  // agent_state is transient-local: a live agent with our id shows up within the
  // participant lease. Its state writer must still be alive for the id to be taken.
  const auto deadline =
      dds::Clock::now() + dds::ToDuration(1.5 * config_.network.participant_lease_s);
  while (!stop_requested_ && dds::Clock::now() < deadline) Pump(deadline);
  for (const auto& [writer, token] : same_id_writers_) {
    if (state_writers_.IsAlive(writer)) {
      log_->error("writer {} publishes agent id {} with token {:016x}", dds::ToString(writer),
                  options_.id, token);
      return true;
    }
  }
  return false;
}

std::optional<std::pair<StepIndex, std::optional<RangeObservation>>> AgentApp::WaitForNextStep() {
  const auto timeout = dds::ToDuration(config_.network.step_timeout_s);
  auto silent_since = dds::Clock::now();
  bool outage_logged = false;
  active_step_ = done_ + 1;
  while (!stop_requested_) {
    ranges_.erase(ranges_.begin(), ranges_.upper_bound(done_));
    truth_seen_.erase(truth_seen_.begin(), truth_seen_.upper_bound(done_));
    const auto now = dds::Clock::now();
    if (!ranges_.empty()) {
      if (outage_logged) log_->info("measurements from the target resumed at step {}", ranges_.rbegin()->first);
      auto newest = *ranges_.rbegin();  // the newest: anything older is already stale
      return std::make_pair(newest.first, std::optional<RangeObservation>(newest.second));
    }
    if (end_of_run_) return std::nullopt;
    // The target is stepping without a range for us (it does not count us alive yet):
    // after a timeout, follow its time by prediction alone.
    if (!truth_seen_.empty() && now - truth_seen_.rbegin()->second >= timeout) {
      const StepIndex k = truth_seen_.rbegin()->first;
      log_->warn("no range for step {}: predicting only", k);
      return std::make_pair(k, std::optional<RangeObservation>());
    }
    if (!outage_logged && done_ > 0 && now - silent_since >= timeout) {
      log_->warn("no measurements from target since step {}", done_);
      outage_logged = true;
    }
    if (!truth_seen_.empty()) silent_since = now;
    Pump(now + std::chrono::milliseconds(100));
  }
  return std::nullopt;
}

void AgentApp::DoStep(StepIndex k, const std::optional<RangeObservation>& z) {
  active_step_ = k;
  // First half: predict and compute our own (i_j, I_j) (eqs 4.45-4.46, 4.49-4.51).
  std::optional<Contribution> own = core_.BeginStep(k, z);
  if (own) {
    deif_msgs::Contribution msg = ToIdl(*own);
    contribution_writer_->write(&msg);
    asserter_->NoteWrite(contribution_writer_);
    held_[k][options_.id] = *own;
  }

  // Wait for every alive member's contribution for k and its state k-1, a timeout, or a
  // newer range (the target moved on without us).
  if (z) {
    const double wait_s = config_.scenario.mode == StepMode::kRealTime
                              ? std::min(config_.scenario.period_s, config_.network.step_timeout_s)
                              : config_.network.step_timeout_s;
    const auto deadline = dds::Clock::now() + dds::ToDuration(wait_s);
    while (!stop_requested_ && !HoldsEverythingFor(k) && dds::Clock::now() < deadline) {
      if (!ranges_.empty() && ranges_.rbegin()->first > k) break;
      Pump(deadline);
    }
    if (!HoldsEverythingFor(k) && !stop_requested_) {
      std::string contributions, states;
      for (AgentId m : Members()) {
        if (m == options_.id) continue;
        if (held_[k].count(m) == 0) contributions += " " + std::to_string(m);
        auto pos = positions_.find(m);
        if (pos == positions_.end() || pos->second.count(k - 1) == 0) states += " " + std::to_string(m);
      }
      std::size_t unknown = 0;
      for (const auto& writer : contribution_writers_.AliveUnknown()) unknown += ignored_writers_.count(writer) == 0;
      log_->warn("step {}: fusing without all members (missing contributions:{}; states of step {}:{}; "
                 "{} alive writers not yet identified)", k, contributions, k - 1, states, unknown);
    }
  }

  // Fuse ours and every eligible peer's: the same set at every agent that saw the same
  // history, whatever the arrival order. A contribution that died with its sender is
  // still fused when it arrived.
  std::vector<Contribution> fused;
  std::set<AgentId> fused_ids;
  for (const auto& [id, c] : held_[k]) {
    if (id == options_.id || Eligible(id, k)) {
      fused.push_back(c);
      fused_ids.insert(id);
    } else {
      Drop(id, "not in step (joined after this step began)");
    }
  }
  const auto positions = MemberPositions(k, fused);
  // Second half: fuse in ascending id (eqs 4.47-4.48), control law, move.
  AgentSnapshot snapshot = core_.FinishStep(k, fused, positions);
  snapshot.alive = static_cast<int>(Members().size());
  held_.erase(held_.begin(), held_.upper_bound(k));
  fused_last_step_ = std::move(fused_ids);
  done_ = k;
  active_step_ = k + 1;
  Publish(snapshot, /*write_csv=*/true);
}

bool AgentApp::Eligible(AgentId m, StepIndex k) const {
  // m takes part in step k when it is in step with us: we fused it at k-1, or we hold its
  // state of step k-1 or later (so the target measured its range k from there). A process
  // that has just (re)joined becomes eligible one step after its first state, so no peer
  // waits for a contribution it cannot have.
  if (done_ == k - 1 && fused_last_step_.count(m) > 0) return true;
  auto pos = positions_.find(m);
  return pos != positions_.end() && !pos->second.empty() && pos->second.rbegin()->first >= k - 1;
}

bool AgentApp::HoldsEverythingFor(StepIndex k) const {
  // At the first step, an alive contribution writer whose agent id is still unknown (its
  // state has not arrived yet) is waited for too.
  if (k == 1) {
    for (const auto& writer : contribution_writers_.AliveUnknown()) {
      if (ignored_writers_.count(writer) == 0) return false;
    }
  }
  for (AgentId m : Members()) {
    if (m == options_.id || !Eligible(m, k)) continue;
    auto held = held_.find(k);
    if (held == held_.end() || held->second.count(m) == 0) return false;
    auto pos = positions_.find(m);
    if (pos == positions_.end() || pos->second.count(k - 1) == 0) return false;
  }
  return true;
}

std::map<AgentId, Vector2> AgentApp::MemberPositions(StepIndex k, const std::vector<Contribution>& fused) const {
  // The ring of this step: this agent and every agent fused, each at its position of step
  // k-1 (the one its range was measured from), as in the in-process simulation where the
  // members of a step are exactly the agents that contribute to it.
  std::set<AgentId> ids;
  for (const auto& c : fused) ids.insert(c.agent_id);
  std::map<AgentId, Vector2> positions;
  positions[options_.id] = core_.position();  // our position at k-1
  for (AgentId id : ids) {
    if (id == options_.id) continue;
    auto it = positions_.find(id);
    if (it == positions_.end()) continue;
    auto at = it->second.upper_bound(k - 1);  // the latest position at or before k-1
    if (at == it->second.begin()) continue;
    positions[id] = std::prev(at)->second;
  }
  return positions;
}

std::set<AgentId> AgentApp::Members() const {
  std::set<AgentId> members = contribution_writers_.AliveIds();
  members.insert(options_.id);
  return members;
}

void AgentApp::Publish(const AgentSnapshot& snapshot, bool write_csv) {
  deif_msgs::AgentState msg = ToIdl(snapshot, options_.id, instance_token_);
  state_writer_->write(&msg);
  asserter_->NoteWrite(state_writer_);
  published_positions_.push_back(snapshot.position_m);
  while (published_positions_.size() > kKeptPositionSteps) published_positions_.pop_front();
  if (csv_ && write_csv) {
    AgentRow row;
    row.step = snapshot.step;
    row.t_s = static_cast<double>(snapshot.step) * config_.scenario.dt_s;
    row.estimate_m = snapshot.estimate_m;
    row.covariance = snapshot.covariance;
    row.position_m = snapshot.position_m;
    row.angle_rad = snapshot.angle_rad;
    row.alive = snapshot.alive;
    row.fused = snapshot.fused;
    row.rejected = rejected_;
    row.dropped = dropped_;
    csv_->Write(row);
  }
}

// ---------------------------------------------------------------------------------------
void AgentApp::Pump(dds::Clock::time_point deadline) {
  for (const Event& event : inbox_.WaitUntil(deadline)) Handle(event);
}

void AgentApp::Handle(const Event& event) {
  std::visit(
      [this](const auto& e) {
        using E = std::decay_t<decltype(e)>;
        if constexpr (std::is_same_v<E, TruthEvent>) {
          if (e.msg.step() == dds::kEndOfRunStep) {
            if (!end_of_run_) log_->info("the target announced the end of the run");
            end_of_run_ = true;
          } else {
            newest_target_step_ = std::max<StepIndex>(newest_target_step_, e.msg.step());
            if (e.msg.step() > done_) truth_seen_.emplace(e.msg.step(), dds::Clock::now());
          }
        } else if constexpr (std::is_same_v<E, RangeEvent>) {
          OnRange(e.msg);
        } else if constexpr (std::is_same_v<E, ContributionEvent>) {
          OnContribution(e.msg, e.writer);
        } else if constexpr (std::is_same_v<E, StateEvent>) {
          OnState(e.msg, e.writer);
        } else if constexpr (std::is_same_v<E, WriterEvent>) {
          OnWriterChanged(e);
        } else {
          static_assert(kAlwaysFalse<E>, "unhandled event");
        }
      },
      event);
}

void AgentApp::OnRange(const deif_msgs::Range& msg) {
  if (msg.step() <= done_) return;
  const RangeObservation z = ToRangeObservation(msg);
  // The target measures from a position this agent published. A range from the target's
  // transient-local history that was measured for an earlier process with our id is stale.
  const bool ours = std::any_of(published_positions_.begin(), published_positions_.end(),
                                [&z](const Vector2& p) { return p == z.p_sensor; });
  if (!ours) {
    if (logged_.emplace(options_.id, "stale range").second) {
      log_->warn("ignored a range for step {} measured from a position this process never "
                 "published (stale, logged once)", msg.step());
    }
    return;
  }
  newest_target_step_ = std::max<StepIndex>(newest_target_step_, msg.step());
  ranges_[msg.step()] = z;
}

// Every process of a run reads the same config: the ids are 1..agents.count.
bool AgentApp::ValidPeerId(AgentId id) const { return id >= 1 && id <= config_.agents.count; }

void AgentApp::OnContribution(const deif_msgs::Contribution& msg, const dds::WriterKey& writer) {
  if (writer == own_contribution_writer_) return;  // ours is held directly
  const AgentId peer = msg.agent_id();
  // Identity first: an unknown id, our own id from another writer, or a writer that
  // changes its id is refused, and that writer is never counted as a member.
  const auto known = contribution_writers_.IdOf(writer);
  // A writer not yet bound to an id that claims one a live writer already speaks for is an
  // impersonation: the first live writer of an id keeps it until it dies.
  const bool id_taken = !known && contribution_writers_.AliveIds().count(peer) > 0;
  if (!ValidPeerId(peer) || peer == options_.id || (known && *known != peer) || id_taken) {
    ignored_writers_.insert(writer);
    Reject(peer, !ValidPeerId(peer) ? "unknown agent id" : "agent id clash");
    return;
  }
  if (contribution_writers_.OnSample(writer, peer, dds::Clock::now())) {
    log_->info("agent {} is a member (writer {})", peer, dds::ToString(writer));
  }
  const Contribution c = ToContribution(msg);
  // Validate before anything can touch an estimate.
  const RejectReason reason = ValidateContribution(c);
  if (reason != RejectReason::kNone) {
    Reject(peer, ToString(reason));
    return;
  }
  const StepIndex window = config_.network.fusion_window_steps;
  // The window is centred on the step in work, or on the target's newest step when this
  // agent is behind (after a restart it jumps there, see run()).
  const StepIndex centre = std::max(active_step_, newest_target_step_);
  if (c.step < centre - window || c.step > centre + window) {
    Drop(peer, "step outside the fusion window");
  } else if (c.step <= done_) {
    Drop(peer, "late (step already fused)");
  } else if (held_[c.step].count(peer) > 0) {
    Drop(peer, "duplicate (agent, step)");  // the first one wins
  } else {
    held_[c.step][peer] = c;
  }
}

void AgentApp::OnState(const deif_msgs::AgentState& msg, const dds::WriterKey& writer) {
  if (writer == own_state_writer_) return;
  const AgentId peer = msg.agent_id();
  if (peer == options_.id) {
    if (msg.instance_token() != instance_token_) same_id_writers_[writer] = msg.instance_token();
    return;
  }
  if (!ValidPeerId(peer)) return;
  state_writers_.OnSample(writer, peer, dds::Clock::now());
  participant_ids_[dds::ParticipantOf(writer)] = peer;
  IdentifyContributionWriters();
  auto& steps = positions_[peer];
  steps[msg.step()] = ToEigenPosition(msg);
  while (steps.size() > kKeptPositionSteps) steps.erase(steps.begin());
  auto& estimates = estimates_[peer];
  estimates[msg.step()] = {ToEigenEstimate(msg), ToEigenCovariance(msg)};
  while (estimates.size() > kKeptPositionSteps) estimates.erase(estimates.begin());
}

std::optional<AgentId> AgentApp::AdoptPeerEstimate(StepIndex step) {
  for (AgentId m : Members()) {  // ascending id: every rejoiner picks the same peer
    if (m == options_.id) continue;
    const auto peer = estimates_.find(m);
    if (peer == estimates_.end()) continue;
    const auto at = peer->second.find(step);
    if (at == peer->second.end()) continue;
    const auto& [estimate, covariance] = at->second;
    // Published data is validated like any peer data before it can become our estimate.
    if (!estimate.allFinite() || !covariance.allFinite() || covariance(0, 0) <= 0.0 ||
        covariance.determinant() <= 0.0) {
      continue;
    }
    core_.AdoptEstimate(estimate, covariance);
    return m;
  }
  return std::nullopt;
}

void AgentApp::OnWriterChanged(const WriterEvent& event) {
  if (event.topic == WriterTopic::kAgentState) {
    state_writers_.OnWriterChanged(event.writer, event.alive);
    return;
  }
  if (event.writer == own_contribution_writer_) return;
  const auto id = contribution_writers_.OnWriterChanged(event.writer, event.alive);
  IdentifyContributionWriters();
  if (!id || ignored_writers_.count(event.writer) > 0) return;
  if (event.alive) {
    log_->info("agent {} is alive again; members now {}", *id, Members().size());
    return;
  }
  const auto last = contribution_writers_.LastSampleOf(*id);
  const double since_s =
      last ? std::chrono::duration<double>(dds::Clock::now() - *last).count() : -1.0;
  log_->warn("agent {} lost (liveliness) {:.3f} s after its last contribution; members now {}",
             *id, since_s, Members().size());
}

void AgentApp::IdentifyContributionWriters() {
  // get_key_value is unsupported: a contribution writer is known by its samples, or by the
  // agent_state samples of the same participant (the GUID prefix), which come first.
  for (const auto& writer : contribution_writers_.AliveUnknown()) {
    if (ignored_writers_.count(writer) > 0) continue;
    auto it = participant_ids_.find(dds::ParticipantOf(writer));
    if (it != participant_ids_.end()) contribution_writers_.Identify(writer, it->second);
  }
}

void AgentApp::Reject(AgentId peer, const std::string& reason) {
  ++rejected_;
  if (logged_.emplace(peer, "rejected: " + reason).second) {
    log_->warn("rejected a contribution from agent {}: {} (logged once)", peer, reason);
  }
}

void AgentApp::Drop(AgentId peer, const std::string& reason) {
  ++dropped_;
  if (logged_.emplace(peer, "dropped: " + reason).second) {
    log_->warn("dropped a contribution from agent {}: {} (logged once)", peer, reason);
  }
}

}  // namespace deif::agent
