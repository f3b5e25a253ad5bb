#include "agent/agent_node.hpp"

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <set>
#include <string>
#include <type_traits>
#include <vector>

#include <nlohmann/json.hpp>
#include <spdlog/fmt/fmt.h>

namespace deif::agent {

namespace {

constexpr double kMaxWaitS = 0.5;  // the loop wakes at least this often (stop requests)
constexpr double kResumedAfterPeriods = 3.0;  // a loop back this many periods late was away (OnResumed)
// How often it looks at every peer's process (docs/PROTOCOL.md, "A process that ended"): to
// see each alive once; and at those the target's roll call left out (the target looks
// often, for everyone).
constexpr double kEndedCheckS = 2.0;
constexpr double kEndedCheckSuspectS = 0.02;
// Writers kept per parent: its relay writer, and that of each process that restarted as it.
constexpr std::size_t kMaxParentWriters = 16;

protocol::AgentProtocol::Options ProtocolOptions(const dds::ProcessContext& context, AgentId id,
                                                 std::uint64_t token, const dds::Timings& timings) {
  protocol::AgentProtocol::Options options;
  options.peer_grace_s = timings.peer_grace_s;
  options.roll_call_membership = EffectiveMembership(context.config) == MembershipKind::kRollCall;
  options.run = protocol::RunTokenOf(context.run_name);
  options.instance_token = token;
  options.resume_after = dds::LastStepAppendedTo(context, AgentCsvName(id), &ReadAgentCsv, "joining as a new agent");
  return options;
}

}  // namespace

AgentNode::AgentNode(dds::ProcessContext& context, AgentId id)
    : context_(context),
      config_(context.config),
      id_(id),
      instance_token_(dds::RandomInstanceToken()),
      timings_(dds::EffectiveTimings(context.config)),
      node_(context.config, "agent-" + std::to_string(id), context.run_name),
      protocol_(context.config, id, ProtocolOptions(context, id, instance_token_, timings_)),
      discovery_watch_(dds::DiscoveryPatienceS(context.config, dds::RestartsInPlace())),
      forgetting_(timings_) {
  if (context_.options.append && !context_.options.out_dir.empty()) {
    earlier_counters_ = dds::EarlierCounters(CountersPath(), *context_.log);
  }
  node_.AddWriter(dds::Topic::kContribution);
  node_.AddWriter(dds::Topic::kAgentState);
  node_.AddReader({dds::Topic::kRange, id_});        // only this agent's ranges
  // Garbage under ids no agent of the run has is dropped as it arrives (and counted). With
  // membership from the roll call, no reader: the peers' contributions come along the tree,
  // and their writers are matched by no agent (docs/PROTOCOL.md, "Membership from the roll
  // call"); the writer stays, its key the identity its contributions are relayed under.
  if (!RollCallMembership()) {
    node_.AddReader({dds::Topic::kContribution, {}, std::make_pair(AgentId{1}, AgentId{config_.agents.count})});
  }
  // Only states claiming this id, for the start check of AnotherProcessHasThisId and no
  // longer: every peer's state writer matches a reader filtered to one id and sends it
  // traffic about the samples it filters out, which doubled the packets of a step
  // (docs/BENCHMARKS.md, "Readers that want nothing"). Once running, another process that
  // speaks for this id shows in its contributions (agent_id_clash).
  node_.AddReader({dds::Topic::kAgentState, id_});
  if (EffectiveExchange(config_) == ExchangeKind::kTree) {
    // Relay partitions (docs/SCALING.md): up.<id> holds the batches of this agent's
    // children, down.<id> its own batches to them; the writer up and the reader down move
    // to the parent's as the tree changes. It starts in the tree of every agent of the run.
    // A parent that fell silent stays out of this agent's tree for twice the time every
    // agent's membership takes to lose a dead agent (its writers' lease plus the grace).
    const double lost_after_s = timings_.liveliness_lease_s + timings_.peer_grace_s;
    tree_.emplace(config_, protocol::TreeExchange::Options{id_, protocol::RunTokenOf(context.run_name),
                                                            node_.WriterKey(dds::Topic::kContribution),
                                                            2.0 * lost_after_s});
    PlaceRelays(tree_->place().parent, /*move=*/false);
    node_.AddWriter(dds::Topic::kRelayUp);
    node_.AddWriter(dds::Topic::kRelayDown);
    node_.AddReader({dds::Topic::kRelayUp, {}});
    node_.AddReader({dds::Topic::kRelayDown, {}});
  }
  if (node_.AuthenticationRestarts() > 0) {
    context_.log->warn("authentication with a peer stalled at start; participant created anew {} "
                       "time(s) (docs/SECURITY.md, \"Start-up\")",
                       node_.AuthenticationRestarts());
  }
  context_.log->info("agent {} up: run '{}', domain {}, token {:016x}", id_, context_.run_name,
                     config_.network.domain_id, instance_token_);
  if (tree_ && RollCallMembership()) {
    context_.log->info("exchange: tree, fan-out {}, parent {}; membership: the target's roll call "
                       "(docs/PROTOCOL.md)",
                       EffectiveTreeFanout(config_), ParentName(tree_->place().parent));
  } else if (tree_) {
    context_.log->info("exchange: tree, fan-out {}, parent {}; a silent peer is lost after {:.2f} s "
                       "(lease {:.2f} s, renewed every {:.2f} s, grace {:.2f} s) (docs/SCALING.md)",
                       EffectiveTreeFanout(config_), ParentName(tree_->place().parent),
                       timings_.liveliness_lease_s + timings_.peer_grace_s, timings_.liveliness_lease_s,
                       timings_.liveliness_lease_s / timings_.assertions_per_lease, timings_.peer_grace_s);
  } else {
    context_.log->info("exchange: all to all");
  }
}

void AgentNode::Stop() {
  stop_requested_.store(true);
  node_.Wake();
}

bool AgentNode::AnotherProcessHasThisId() {
  // agent_state is transient-local: a live process with this id shows up within a couple of
  // participant announcements. Our own writers are not alive to anyone yet.
  const double wait_s = std::max(1.0, 2.0 * config_.network.participant_announcement_s);
  const auto deadline = dds::Clock::now() + std::chrono::duration_cast<dds::Clock::duration>(
                                                std::chrono::duration<double>(wait_s));
  while (!stop_requested_ && dds::Clock::now() < deadline) {
    for (dds::Event& event : node_.Wait(deadline)) {
      const auto* state = std::get_if<dds::Received<protocol::StateMsg>>(&event);
      if (state != nullptr && !Authorised(state->msg.agent_id, state->from)) {
        early_events_.push_back(std::move(event));  // counted once the protocol runs
        continue;
      }
      if (state == nullptr) early_events_.push_back(std::move(event));
      if (state != nullptr && state->msg.agent_id == id_ &&
          state->msg.run == protocol::RunTokenOf(context_.run_name) &&
          state->msg.instance_token != instance_token_) {
        context_.log->error("agent id {} is already live in run '{}' (writer {}, token {:016x})", id_,
                            context_.run_name, protocol::ToString(state->from),
                            state->msg.instance_token);
        return true;
      }
    }
  }
  return false;
}

int AgentNode::Run() {
  if (AnotherProcessHasThisId()) return protocol::kExitDuplicate;
  node_.RemoveReader(dds::Topic::kAgentState);
  if (stop_requested_) return protocol::kExitOk;
  node_.StartLiveliness();  // only now do our writers become alive to the peers
  if (!context_.options.out_dir.empty()) {
    csv_.emplace((std::filesystem::path(context_.options.out_dir) / AgentCsvName(id_)).string(),
                 context_.options.append ? CsvMode::kAppend : CsvMode::kTruncate);
  } else {
    context_.log->warn("no --out folder: {} is not written", AgentCsvName(id_));
  }
  // The initial state carries what the transport has matched so far (never "not reported"):
  // the target must not take it for an agent that does not report (docs/PROTOCOL.md, "Start").
  ReportMatches(dds::ToSeconds(dds::Clock::now()));
  protocol_.Start(dds::ToSeconds(dds::Clock::now()));
  for (const dds::Event& event : early_events_) Dispatch(event, dds::ToSeconds(dds::Clock::now()));
  early_events_.clear();
  Pump();
  context_.log->info("published the initial state; waiting for the target");

  while (!stop_requested_ && !protocol_.finished()) {
    std::optional<double> wake = protocol_.NextDeadline();
    if (tree_) {
      const std::optional<double> relay = tree_->NextDeadline();
      if (relay && (!wake || *relay < *wake)) wake = relay;
    }
    if (const std::optional<double> waited = WaitedForFromS()) {
      // Its look at the processes of the members a lock-step step waits for is due then, and
      // every kEndedCheckSuspectS after (EndedAgents below): the loop must wake for it.
      const double look_s = std::max(*waited, dds::ToSeconds(dds::Clock::now()) + kEndedCheckSuspectS);
      if (!wake || look_s < *wake) wake = look_s;
    }
    const dds::Clock::time_point wake_by = dds::WakeBy(wake, kMaxWaitS);
    const double wait_from_s = dds::ToSeconds(dds::Clock::now());
    const std::vector<dds::Event> events = node_.Wait(wake_by);
    const double now_s = dds::ToSeconds(dds::Clock::now());
    if (last_loop_s_ >= 0.0 && now_s - last_loop_s_ > AwayAfterS()) {
      // This process was frozen or starved: the lapses it now sees are of its own making
      // (it read nothing), for as long as its peers take to renew their liveliness.
      const double hold_s =
          std::max(timings_.liveliness_lease_s, EffectiveRelayLeaseS(config_)) +
          config_.network.liveliness_grace_s;
      // Where the time went, for whoever reads the log: handling and publishing (a write
      // that blocked), or the wait, and how far past its wake-up it returned (frozen or
      // starved).
      context_.log->info(
          "the loop stood still for {:.2f} s ({:.2f} s handling and publishing, {:.2f} s waiting, back {:.2f} s "
          "after its wake-up): peers' lapses count only after {:.2f} s more",
          now_s - last_loop_s_, wait_from_s - last_loop_s_, now_s - wait_from_s,
          std::max(0.0, now_s - dds::ToSeconds(wake_by)), hold_s);
      protocol_.OnAway(now_s, hold_s);
      if (tree_) tree_->OnAway(now_s, hold_s);
    }
    if (now_s - dds::ToSeconds(wake_by) > kResumedAfterPeriods * config_.scenario.period_s) {
      // It overslept its wake-up by several periods (frozen, or starved for long): the steps
      // it slept through wait a moment for what its sockets hold (AgentProtocol::OnResumed).
      // Not after a shorter delay, which a loaded host gives now and then: the hold delays
      // its next contribution too.
      protocol_.OnResumed(now_s);
    }
    last_loop_s_ = now_s;
    // From the first step on: before it, what arrives comes from the DDS histories of
    // writers just matched, and its delay is the wait for the start (docs/ARTEFACTS.md).
    if (protocol_.last_written_step() >= 1) delivery_.Record(events);
    // The members the tree is made of, once the run has begun (before, discovery is still
    // going on and the tree of every agent of the run stands).
    if (tree_ && tree_live_) {
      const auto version = std::make_pair(node_.ParticipantsVersion(), protocol_.membership_version());
      if (version != tree_version_) {  // only then: building the members costs
        tree_version_ = version;
        tree_->SetMembers(TreeMembers(), now_s);
      }
    }
    for (const dds::Event& event : events) {
      forgetting_.Note(event, now_s);
      Dispatch(event, now_s);
    }
    // More often while the target's roll call leaves out a member (the target may have seen
    // its process end already), or a lock-step step waits long for a member (it may have
    // been killed in the step, and the target waits for this agent).
    for (const protocol::SenderKey& ended :
         node_.EndedAgents(kEndedCheckS, [this] { return protocol_.MembersOutOfRollCall(); }, kEndedCheckSuspectS,
                           [this, now_s] { return WaitedFor(now_s); })) {
      protocol_.OnProcessEnded(ended, now_s);
    }
    ReportMatches(now_s);
    protocol_.OnUnknownIdsDropped(node_.DroppedByIdRange());
    dds::LogReadersMadeAnew(node_, *context_.log);
    if (tree_) tree_->OnTimer(now_s);
    protocol_.OnTimer(now_s);
    Pump();
    if (now_s >= counters_due_s_) {  // a kill -9 loses at most the last second of them
      WriteCounters();
      counters_due_s_ = now_s + dds::kCountersEveryS;
    }
    if (protocol_.finished()) break;  // the run is over: nothing to start again for (as the target)
    if (dds::Node::ReceiveStuck() || DeafForTest()) return Deaf();
    if (ThrowForTest()) dds::ThrowInAThreadForTest();
    if (CrashForTest()) dds::CrashInAThreadForTest();
    if (ReaderLoopForTest()) dds::LoopOverALostChangeForTest();
    if (dds::RestartForLostPorts(node_, *context_.log, "after step " + std::to_string(protocol_.last_written_step()),
                                 watching_ports_)) {
      WriteCounters();
      restart_in_place_ = true;
      return protocol::kExitRuntimeError;  // the exit code if it cannot start again
    }
    if (DiscoveryStoppedShort(now_s) || ForgottenByTheServer(now_s)) {
      WriteCounters();
      return protocol::kExitRuntimeError;  // the exit code if it cannot start again
    }
  }
  protocol_.OnUnknownIdsDropped(node_.DroppedByIdRange());
  if (stop_requested_) {
    context_.log->info("stopped after step {}", protocol_.last_written_step());
    WriteCounters();
    return protocol::kExitOk;
  }
  // Let reliable peers receive our last samples before the writers go away (bounded: a
  // peer that died meanwhile never acknowledges).
  const bool acknowledged = node_.WaitForAcknowledgments(0.5);
  const auto& c = protocol_.counters();
  context_.log->info("rejected {}, dropped {}, late {}, deadline misses {}, adoptions {}, merges {}, "
                     "liveliness lapses forgiven {}; last samples {}acknowledged",
                     c.rejected, c.dropped, c.late, c.deadline_misses, c.adoptions, c.merges,
                     protocol_.lapses_forgiven(), acknowledged ? "" : "not all ");
  for (const auto& [reason, count] : c.by_reason) context_.log->info("  {}: {}", reason, count);
  if (const std::string delays = delivery_.Summary(); !delays.empty()) {
    context_.log->info("delivery delays p50 / p99 [ms]: {}", delays);
  }
  WriteCounters();
  return exit_code_.value_or(protocol::kExitOk);
}

bool AgentNode::ThrowForTest() {
  static const StepIndex at_step = dds::FaultThrowStep(std::to_string(id_));
  if (threw_for_test_ || at_step == 0 || protocol_.last_written_step() < at_step) return false;
  threw_for_test_ = true;
  return true;
}

bool AgentNode::CrashForTest() {
  static const StepIndex at_step = dds::FaultCrashStep(std::to_string(id_));
  if (crashed_for_test_ || at_step == 0 || protocol_.last_written_step() < at_step) return false;
  crashed_for_test_ = true;
  return true;
}

bool AgentNode::ReaderLoopForTest() const {
  static const StepIndex at_step = dds::FaultReaderLoopStep(std::to_string(id_));
  return at_step > 0 && protocol_.last_written_step() >= at_step;
}

bool AgentNode::DeafForTest() const {
  static const StepIndex at_step = dds::FaultDeafStep(std::to_string(id_));
  return at_step > 0 && protocol_.last_written_step() >= at_step;
}

int AgentNode::Deaf() {
  // Fast DDS 2.9.1 cannot recover the port (docs/FASTDDS_NOTES.md, "A receive loop stuck on a
  // dead writer's segment"); a new participant can. The rows written so far are kept: the
  // new process appends to them and rejoins as a restarted agent does (docs/PROTOCOL.md).
  WriteCounters();
  restart_in_place_ = dds::MayRestartInPlace(*context_.log, dds::kReceiveStuck,
                                             "after step " + std::to_string(protocol_.last_written_step()));
  return protocol::kExitRuntimeError;  // the exit code when it does not start again
}

bool AgentNode::DiscoveryStoppedShort(double now_s) {
  // Every agent of the run whose participant is up should have a contribution writer this
  // agent's reader matched, and the target's participant up a range writer; with a Discovery
  // Server the target should be up at all (docs/FASTDDS_NOTES.md, "Endpoint discovery that
  // stops short"). Not with security: there a participant is created anew when its handshake
  // stalls, and names are checked by permissions.
  if (node_.Secure() || !discovery_watch_.Due(now_s)) return false;
  int peers = 1;  // its own writer
  for (AgentId j : node_.AgentsUp()) {
    peers += j != id_ && j >= 1 && j <= static_cast<AgentId>(config_.agents.count) ? 1 : 0;
  }
  const bool target = node_.TargetUp();
  const bool server = config_.network.discovery == DiscoveryKind::kServer;
  // Both ways: its reader matched every peer's writer, its writer every peer's reader (only
  // the side that misses an endpoint can tell). With membership from the roll call, the
  // four ends of its links in the tree instead (TreeLinksMatched).
  int expected = 2 * peers + (target || server ? 1 : 0);
  int matched = (target ? std::min(node_.MatchedWriters(dds::Topic::kRange), 1) : 0);
  if (RollCallMembership()) {
    // Only the links to the agents whose participants are up: one cut off by a partition,
    // gone from the participants, stays in this agent's tree for as long as no roll call
    // reaches it (docs/PROTOCOL.md, "Membership from the roll call").
    const protocol::TreePlace& place = tree_->place();
    const std::set<AgentId> up = node_.AgentsUp();
    const int parent = place.parent && up.count(*place.parent) > 0 ? 1 : 0;
    const int children = static_cast<int>(
        std::count_if(place.children.begin(), place.children.end(), [&](AgentId c) { return up.count(c) > 0; }));
    expected = 2 * parent + 2 * children + (target || server ? 1 : 0);
    matched += std::min(node_.MatchedReaders(dds::Topic::kRelayUp), parent) +
               std::min(node_.MatchedWriters(dds::Topic::kRelayDown), parent) +
               std::min(node_.MatchedWriters(dds::Topic::kRelayUp), children) +
               std::min(node_.MatchedReaders(dds::Topic::kRelayDown), children);
  } else {
    matched += std::min(node_.MatchedWriters(dds::Topic::kContribution), peers) +
               std::min(node_.MatchedReaders(dds::Topic::kContribution), peers);
  }
  if (!discovery_watch_.Stalled(expected, matched, node_.EndpointsHeard(), now_s)) return false;
  const std::string why = fmt::format(
      "endpoint discovery stopped short: {} peers and {} up, {} of {} contribution and range endpoints matched, unchanged "
      "for {:g} s (docs/FASTDDS_NOTES.md, \"Endpoint discovery that stops short\")",
      peers - 1, target ? "the target" : "no target", matched, expected, discovery_watch_.patience_s());
  if (dds::MayRestartInPlace(*context_.log, why, "after step " + std::to_string(protocol_.last_written_step()))) {
    restart_in_place_ = true;
    return true;
  }
  discovery_watch_.GiveUp();  // said once; it goes on as it is
  return false;
}

bool AgentNode::ForgottenByTheServer(double now_s) {
  // The server dropped this client and told everyone else (docs/FASTDDS_NOTES.md, "Forgotten
  // by the server"). With simple discovery every process times out each lease itself, and
  // the two sides meet again.
  if (config_.network.discovery != DiscoveryKind::kServer || protocol_.last_written_step() < 1) return false;
  const std::optional<std::string> why = forgetting_.Forgotten(node_, [this] { return node_.TargetUp(); }, "nothing", now_s);
  if (!why) return false;
  if (dds::MayRestartInPlace(*context_.log, *why, "after step " + std::to_string(protocol_.last_written_step()))) {
    restart_in_place_ = true;
    return true;
  }
  forgetting_.GiveUp();  // said once; it goes on as it is
  return false;
}

void AgentNode::ReportMatches(double now_s) {
  // Both ways: this agent hears every peer, and every peer hears this agent; and it hears
  // the target.
  int matched = std::min(node_.MatchedWriters(dds::Topic::kContribution),
                         node_.MatchedReaders(dds::Topic::kContribution));
  if (RollCallMembership()) {
    // No pair of agents is matched but along the tree: this agent and the peers it sees up
    // (their participants), once its links are matched (docs/PROTOCOL.md, "Membership from
    // the roll call").
    if (const std::uint64_t version = node_.ParticipantsVersion(); version != peers_up_version_) {
      peers_up_version_ = version;  // only then: AgentsUp builds a set (every pass of the loop)
      peers_up_ = 1;
      for (AgentId j : node_.AgentsUp()) {
        peers_up_ += j != id_ && j >= 1 && j <= static_cast<AgentId>(config_.agents.count) ? 1 : 0;
      }
    }
    matched = peers_up_;
  }
  // Over the tree a step's contributions travel only along its links: until this agent's
  // links to its parent and children are matched both ways, it does not count as hearing
  // everyone (docs/PROTOCOL.md, "Start"). Looked at only when it would count (each look
  // takes an endpoint's lock, and this runs at every pass of the loop).
  if (tree_ && matched >= config_.agents.count && !TreeLinksMatched()) matched = config_.agents.count - 1;
  protocol_.OnPeersMatched(matched, node_.MatchedWriters(dds::Topic::kRange), now_s);
  protocol_.OnTargetParticipant(node_.TargetUp(), now_s);
}

bool AgentNode::TreeLinksMatched() const {
  // The writer up and the reader down are in the parent's partitions, the reader up and
  // the writer down in this agent's own (PlaceRelays): each matches exactly the other end
  // of its links. The root's are in partitions of no one.
  const protocol::TreePlace& place = tree_->place();
  const int parent = place.parent ? 1 : 0;
  const int children = static_cast<int>(place.children.size());
  return node_.MatchedReaders(dds::Topic::kRelayUp) >= parent &&
         node_.MatchedWriters(dds::Topic::kRelayDown) >= parent &&
         node_.MatchedWriters(dds::Topic::kRelayUp) >= children &&
         node_.MatchedReaders(dds::Topic::kRelayDown) >= children;
}

std::string AgentNode::CountersPath() const {
  return (std::filesystem::path(context_.options.out_dir) / ("agent_" + std::to_string(id_) + ".counters.json"))
      .string();
}

void AgentNode::WriteCounters() const {
  if (context_.options.out_dir.empty()) return;
  const auto& c = protocol_.counters();
  const nlohmann::json counters = {{"rejected", c.rejected},   {"dropped", c.dropped},
                                   {"late", c.late},           {"deadline_misses", c.deadline_misses},
                                   {"adoptions", c.adoptions}, {"merges", c.merges},
                                   {"lapses_forgiven", protocol_.lapses_forgiven()},
                                   {"losses_undone", protocol_.losses_undone()},
                                   {"parent_losses_undone", tree_ ? tree_->parent_losses_undone() : 0},
                                   {"links_down_remade", tree_ ? tree_->links_down_remade() : 0},
                                   {"grace_factor", protocol_.grace_factor()},
                                   {"by_reason", c.by_reason}, {"delivery_ms", delivery_.ToJson()}};
  dds::WriteCounters(CountersPath(), dds::AddEarlierCounters(earlier_counters_, counters), *context_.log);
}

bool AgentNode::Authorised(AgentId claimed, const protocol::SenderKey& writer) const {
  return !node_.Secure() || node_.AuthorizedAgent(writer) == claimed;
}

void AgentNode::Dispatch(const dds::Event& event, double now_s) {
  if (const auto* range = std::get_if<dds::Received<protocol::RangeMsg>>(&event)) {
    protocol_.OnRange(range->msg, range->from, now_s);
    // The relay waits for the roll call the protocol accepted (validated, from its target);
    // the own contribution that range makes is carried out after this, in Pump.
    if (tree_) {
      if (const auto roll_call = protocol_.RollCallOf(range->msg.step)) {
        tree_->OnRollCall(range->msg.step, *roll_call, now_s);
        tree_live_ = true;
      }
    }
  } else if (const auto* batch = std::get_if<dds::Received<protocol::BatchMsg>>(&event)) {
    if (!tree_) return;
    if (batch->msg.down && tree_->place().parent == batch->msg.sender_id &&
        parent_writers_.size() < kMaxParentWriters) {
      parent_writers_.emplace(batch->from, batch->msg.sender_id);  // its first batch names it
    }
    tree_->OnBatch(batch->msg, now_s);
  } else if (const auto* c = std::get_if<dds::Received<protocol::ContributionMsg>>(&event)) {
    if (!Authorised(c->msg.agent_id, c->from)) {
      protocol_.OnUnauthorised(c->msg.agent_id, c->from);
      return;
    }
    protocol_.OnContribution(c->msg, c->from, now_s);
  } else if (const auto* state = std::get_if<dds::Received<protocol::StateMsg>>(&event)) {
    // Only from the start check (the reader is gone since): refused samples are counted.
    if (!Authorised(state->msg.agent_id, state->from)) {
      protocol_.OnUnauthorised(state->msg.agent_id, state->from);
    }
  } else if (const auto* change = std::get_if<dds::LivelinessChange>(&event)) {
    if (change->topic == dds::Topic::kContribution || change->topic == dds::Topic::kRange) {
      protocol_.OnWriterLiveliness(change->writer, change->alive, now_s);
    } else if (change->topic == dds::Topic::kRelayDown && tree_) {
      if (auto parent = parent_writers_.find(change->writer); parent != parent_writers_.end()) {
        tree_->OnParentLiveliness(parent->second, change->alive, now_s);
      } else if (auto silent = silent_writers_.find(change->writer); silent != silent_writers_.end()) {
        tree_->OnParentLiveliness(silent->second, change->alive, now_s);
      }
    }
  }
}

void AgentNode::Execute(std::vector<protocol::AgentAction> actions) {
  for (protocol::AgentAction& action : actions) {
    std::visit(
        [this](auto& a) {
          using A = std::decay_t<decltype(a)>;
          namespace act = protocol::agent_action;
          if constexpr (std::is_same_v<A, act::PublishContribution>) {
            if (tree_) {
              tree_->OnOwn(a.msg, dds::ToSeconds(dds::Clock::now()));
            } else {
              node_.Write(a.msg);
            }
          } else if constexpr (std::is_same_v<A, act::PublishState>) {
            node_.Write(a.msg);
          } else if constexpr (std::is_same_v<A, act::WriteRow>) {
            if (csv_) csv_->Write(a.row);
          } else if constexpr (std::is_same_v<A, protocol::Log>) {
            dds::Carry(a, *context_.log);
          } else if constexpr (std::is_same_v<A, protocol::Finish>) {
            dds::Carry(a, *context_.log, exit_code_);
          }
        },
        action);
  }
}

void AgentNode::ExecuteRelay(std::vector<protocol::TreeAction> actions) {
  namespace act = protocol::tree_action;
  std::vector<std::pair<protocol::ContributionMsg, protocol::SenderKey>> deliveries;
  for (protocol::TreeAction& action : actions) {
    if (auto* send = std::get_if<act::Send>(&action)) {
      node_.Write(send->batch);
    } else if (auto* deliver = std::get_if<act::Deliver>(&action)) {
      deliveries.emplace_back(std::move(deliver->item.msg), deliver->item.origin);  // after the sends
    } else if (const auto* reparent = std::get_if<act::Reparent>(&action)) {
      // A parent left for its silence is still watched where it was: its relay writer alive
      // again brings it back (docs/SCALING.md, "A parent heard again").
      bool watch = false;
      if (reparent->silent) {
        for (const auto& [writer, parent] : parent_writers_) {
          if (parent != *reparent->silent || silent_writers_.size() >= kMaxParentWriters) continue;
          silent_writers_.emplace(writer, parent);
          watch = true;
        }
      }
      PlaceRelays(reparent->parent, /*move=*/true, watch);
      parent_writers_.clear();  // the new parent's first batch names its writer
      if (reparent->silent) {
        context_.log->warn("tree exchange: parent now {} ({} members): agent {} fell silent (relay lease {} s)",
                           ParentName(reparent->parent), tree_->members().size(), *reparent->silent,
                           EffectiveRelayLeaseS(config_));
      } else if (reparent->parent && std::any_of(silent_writers_.begin(), silent_writers_.end(), [&](const auto& e) {
                   return e.second == *reparent->parent;
                 })) {
        context_.log->info("tree exchange: parent now {} ({} members): back after it fell silent ({} heard again so far)",
                           ParentName(reparent->parent), tree_->members().size(), tree_->parents_heard_again());
      } else {
        context_.log->info("tree exchange: parent now {} ({} members)", ParentName(reparent->parent),
                           tree_->members().size());
      }
    } else if (const auto* remake = std::get_if<act::RemakeLinkDown>(&action)) {
      if (tree_->place().parent != remake->parent) continue;  // it moved since: its link is new
      context_.log->warn(
          "tree exchange: nothing came down from parent agent {} for {:.1f} s over {} steps, its relay writer "
          "alive: the link down is made anew (docs/SCALING.md, \"A link down that hears nothing\")",
          remake->parent, remake->silent_s, protocol::TreeExchange::kDeafRollCalls);
      node_.RemakeReader(dds::Topic::kRelayDown);
      parent_writers_.clear();  // the parent's next batch names its writer again
    } else if (const auto* grown = std::get_if<act::GraceGrown>(&action)) {
      context_.log->warn("tree exchange: {}",
                         protocol::GraceGrownLine("relay parent agent " + std::to_string(grown->parent),
                                                  grown->factor, grown->grace_s));
    } else if (const auto* reject = std::get_if<act::Reject>(&action)) {
      protocol_.OnRelayRejected(reject->reason, reject->count);
    }
  }
  if (!deliveries.empty()) protocol_.OnContributions(deliveries, dds::ToSeconds(dds::Clock::now()));
}

void AgentNode::DropWatchesOnReturn() {
  if (silent_writers_.empty()) return;
  const std::set<AgentId> silent = tree_->silent_parents();
  for (auto it = silent_writers_.begin(); it != silent_writers_.end();) {
    it = silent.count(it->second) > 0 ? std::next(it) : silent_writers_.erase(it);
  }
  // Each watch is a reader the parent's writer sends every batch to.
  if (silent_writers_.empty()) node_.DropWatches(dds::Topic::kRelayDown);
}

void AgentNode::Pump() {
  for (;;) {
    std::vector<protocol::AgentAction> actions = protocol_.TakeActions();
    std::vector<protocol::TreeAction> relay;
    if (tree_) relay = tree_->TakeActions();
    if (actions.empty() && relay.empty()) {
      if (tree_) DropWatchesOnReturn();
      return;
    }
    Execute(std::move(actions));
    ExecuteRelay(std::move(relay));
  }
}

void AgentNode::PlaceRelays(std::optional<AgentId> parent, bool move, bool keep_watch) {
  // Writer up and reader down in the parent's partitions (none: the root's go nowhere);
  // reader up and writer down in this agent's own.
  const std::string p = parent ? std::to_string(*parent) : "none";
  const std::string self = std::to_string(id_);
  if (move) {
    node_.MoveSubPartitions(dds::Topic::kRelayUp, "up." + p, "up." + self);
    node_.MoveSubPartitions(dds::Topic::kRelayDown, "down." + self, "down." + p, keep_watch);
  } else {
    node_.SetSubPartitions(dds::Topic::kRelayUp, "up." + p, "up." + self);
    node_.SetSubPartitions(dds::Topic::kRelayDown, "down." + self, "down." + p);
  }
}

std::set<AgentId> AgentNode::WaitedFor(double now_s) const {
  std::set<AgentId> waited = protocol_.MembersWaitedFor(now_s);
  if (tree_) {
    for (AgentId child : tree_->ChildrenWaitedFor(now_s, protocol::AgentProtocol::kSuspectAfterS)) waited.insert(child);
  }
  return waited;
}

std::optional<double> AgentNode::WaitedForFromS() const {
  std::optional<double> from = protocol_.WaitedForFromS();
  if (tree_) {
    const std::optional<double> relay = tree_->ChildrenWaitedForFromS(protocol::AgentProtocol::kSuspectAfterS);
    if (relay && (!from || *relay < *from)) from = relay;
  }
  return from;
}

double AgentNode::AwayAfterS() const {
  // The loop wakes at least every kMaxWaitS; away longer than a lease of its peers' writers,
  // they lapse in its view.
  return std::max(2.0 * kMaxWaitS, timings_.liveliness_lease_s);
}

std::string AgentNode::ParentName(std::optional<AgentId> parent) {
  return parent ? "agent " + std::to_string(*parent) : std::string("none, the root");
}

std::set<AgentId> AgentNode::TreeMembers() const {
  std::set<AgentId> members;
  for (AgentId id : node_.AgentsUp()) {
    if (id >= 1 && id <= static_cast<AgentId>(config_.agents.count)) members.insert(id);
  }
  for (AgentId lost : protocol_.LostPeers()) members.erase(lost);
  members.insert(id_);
  return members;
}

bool AgentNode::LeaveQuietly() {
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

}  // namespace deif::agent
