// One process's place on the DDS network: a participant in the run's partition, a writer
// and a reader per topic it uses, with the QoS of docs/ARCHITECTURE.md, and an event loop
// that hands the application every sample and liveliness change in batches on its own
// thread (a WaitSet, no thread hop per sample). Its interface speaks the protocol's
// messages only: no Fast DDS type leaves dds/.
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <set>
#include <utility>
#include <string>
#include <variant>
#include <vector>

#include "common/config/config.hpp"
#include "common/protocol/discovery_watch.hpp"
#include "common/protocol/messages.hpp"
#include "dds/topics.hpp"

namespace deif::dds {

using Clock = std::chrono::steady_clock;

// A sample, the writer that wrote it, and when it wrote it (the DDS source timestamp: the
// writer's wall clock, seconds since the Unix epoch; comparable across processes of one host).
template <typename M>
struct Received {
  M msg;
  protocol::SenderKey from;
  double written_unix_s = 0.0;
};
// A remote writer of `topic` became alive or not alive (liveliness, or it unmatched).
struct LivelinessChange {
  Topic topic;
  protocol::SenderKey writer;
  bool alive;
};
using Event = std::variant<Received<protocol::TruthMsg>, Received<protocol::RangeMsg>,
                           Received<protocol::ContributionMsg>, Received<protocol::StateMsg>,
                           Received<protocol::BatchMsg>, LivelinessChange>;

// What a reader receives. only_id: only the samples keyed to one agent id; id_range: only
// samples keyed to an id in [first, second], the others dropped as they arrive and counted
// (DroppedByIdRange). Content filters, evaluated at the writer where it can be.
struct ReaderSpec {
  Topic topic;
  std::optional<AgentId> only_id;
  std::optional<std::pair<AgentId, AgentId>> id_range = std::nullopt;
};

// What a process does when one of its readers is caught in Fast DDS 2.9.1's loop over a
// change that a keyed history lost track of, from which no call returns: called once, on
// Fast DDS's logging thread, when its error "Change not found on this key" came 1000 times
// within 5 s although Node::Wait makes anew a reader that hands out a sample twice
// (docs/FASTDDS_NOTES.md, "A reader that hands out one sample for ever"). Only the first
// few of those errors are shown. nullptr: nothing is called.
using ReaderLoopHandler = void (*)();
void SetReaderLoopHandler(ReaderLoopHandler handler);
// For tests (DEIF_FAULT_READER_LOOP): the calling thread does what Fast DDS's loop does, for
// ever: it queues that error, in bursts of 100 a millisecond, and never returns.
[[noreturn]] void LoopOverALostChangeForTest();

class Node {
 public:
  // Creates the participant in config.network.domain_id, in the partition of run_name (no
  // partition with network.ros2_naming), with network.transport and network.discovery.
  // Throws std::runtime_error naming what could not be created.
  Node(const Config& config, const std::string& participant_name, const std::string& run_name);
  ~Node();  // deletes every entity, then the participant
  Node(const Node&) = delete;
  Node& operator=(const Node&) = delete;

  void AddWriter(Topic topic);
  void AddReader(const ReaderSpec& spec);
  // The writer and reader of `topic` made after this call join the partition
  // deif.<run>.<suffix> instead of the run's, so they match only endpoints of that
  // sub-partition (a group of the relayed exchange measured by bench/dds_alltoall.cpp).
  // Plain runs only: throws std::logic_error with security or network.ros2_naming.
  void SetSubPartition(Topic topic, const std::string& suffix) { SetSubPartitions(topic, suffix, suffix); }
  // The same, with the writer in deif.<run>.<writer_suffix> and the reader in
  // deif.<run>.<reader_suffix> (the tree exchange of bench/dds_alltoall.cpp).
  void SetSubPartitions(Topic topic, const std::string& writer_suffix, const std::string& reader_suffix);
  // Moves the writer and reader of `topic`, made after SetSubPartitions, to other
  // sub-partitions (a relay of the tree exchange with a new parent): they unmatch the old
  // peers and match the new ones. Both are made anew there (docs/FASTDDS_NOTES.md, "A
  // reader moved and moved back"): the new writer has no history (WriterKey changes), and
  // the samples the old reader held come out of the next Wait(). A writer with liveliness
  // assertions is moved, not made anew.
  // With keep_watch, the old reader is not deleted: it stays where it was as a watch, which
  // hands out no sample (what it receives is dropped) and reports only the liveliness of the
  // writers it matches, as LivelinessChange events of `topic` (a parent of the tree exchange
  // that fell silent is heard again there: docs/SCALING.md, "A parent heard again").
  // From the thread that calls Wait(), never during it.
  void MoveSubPartitions(Topic topic, const std::string& writer_suffix, const std::string& reader_suffix,
                         bool keep_watch = false);
  // Deletes every watch MoveSubPartitions kept of `topic`.
  void DropWatches(Topic topic);
  // How many watches of `topic` there are.
  int Watches(Topic topic) const;
  // Deletes this node's reader of `topic` and makes it anew in the same partitions, with the
  // same QoS and listener: a reader no writer has a record of, announced afresh (a child of
  // the tree exchange that hears nothing from its parent, docs/SCALING.md). What the old
  // one held comes out of the next Wait(). From the thread that calls Wait(), never during it.
  void RemakeReader(Topic topic);
  // Deletes this node's reader of `topic` (and its content filter), if it has one: the
  // peers' writers stop matching it. From the thread that calls Wait(), never during it.
  void RemoveReader(Topic topic);
  // Makes this node passive for good (an observer, docs/LIVE.md): it has no writer, and
  // AddWriter throws std::logic_error from now on, so it never publishes on the network's
  // topics. Throws std::logic_error if it already has a writer.
  void MakePassive();
  // Starts asserting the liveliness of every writer with MANUAL_BY_TOPIC liveliness (range,
  // contribution, agent_state) network.liveliness_assertions_per_lease times per lease,
  // skipping writers that wrote within that period. Until then they are not alive to peers.
  void StartLiveliness();

  void Write(const protocol::TruthMsg& msg);
  void Write(const protocol::RangeMsg& msg);
  void Write(const protocol::ContributionMsg& msg);
  void Write(const protocol::StateMsg& msg);
  void Write(const protocol::BatchMsg& msg);  // on deif/relay_down if msg.down, else relay_up

  // Waits until a sample or a liveliness change arrives, Wake() is called, or the
  // deadline; returns everything that arrived, in order per reader.
  std::vector<Event> Wait(Clock::time_point deadline);
  // Thread-safe: makes a Wait() return at once.
  void Wake();

  // Waits until every matched reader acknowledged this node's samples, for `seconds` in all,
  // every writer at once (a reader that left without a goodbye never acknowledges, and the
  // target has a writer per agent).
  bool WaitForAcknowledgments(double seconds);
  // Whether network.security.enabled (docs/SECURITY.md).
  bool Secure() const;
  // With security: the agent id the remote `writer` may speak for, the J of the partition
  // deif.<run>.agent.<J> it publishes in, which the CA-signed permissions of its participant
  // must allow before any reader here matches it. Bound at the writer's discovery; nullopt
  // for good once it announces other partitions. nullopt for the target, an observer, an
  // unknown writer, and without security.
  std::optional<AgentId> AuthorizedAgent(const protocol::SenderKey& writer) const;
  // With security: how often the participant was created anew at start because the
  // authentication with a peer stalled (docs/SECURITY.md, "Start-up"). 0 without.
  int AuthenticationRestarts() const;
  // This node's writer of `topic` as peers see it.
  protocol::SenderKey WriterKey(Topic topic) const;
  // Leaves the domain without a goodbye: nothing of the participant is deleted, now or
  // later, and the process must end with std::_Exit soon after (its peers see it leave one
  // liveliness lease later, as after kill -9). Fast DDS 2.9.1 can abort a peer in
  // PDP.cpp:1140 when a participant says goodbye while the peer's lease check of it runs;
  // when a whole run ends at once that happened to 4 of 64 agents (docs/FASTDDS_NOTES.md).
  void Abandon();
  // Whether the run's target is up: a participant named "target" that announced this run
  // is discovered and not gone, whether or not its endpoints exist yet (a target of a large
  // run takes seconds to make them). Not with ros2_naming (false).
  bool TargetUp() const;
  // With a Discovery Server: since when (ToSeconds) its participant is listed up, this time;
  // nullopt while it is not.
  std::optional<double> DiscoveryServerSinceS() const;
  // The agent ids of the participants named agent-<id> that announced this run and are up
  // (discovered, not gone), whatever their endpoints. Empty with ros2_naming.
  std::set<AgentId> AgentsUp() const;
  // Changes whenever a participant is discovered or gone (AgentsUp may have changed).
  std::uint64_t ParticipantsVersion() const;
  // How many remote writers and readers this participant has discovered so far, in any
  // partition and topic: it grows while discovery is under way anywhere.
  std::uint64_t EndpointsHeard() const;
  // True once a shared-memory receive thread of this process is stuck for good on a message
  // of a dead writer whose segment is gone (Fast DDS 2.9.1; docs/FASTDDS_NOTES.md, "A
  // receive loop stuck on a dead writer's segment"): the process hears nothing more on that
  // port. A process-wide fact, read from Fast DDS's log; only a new participant hears again.
  static bool ReceiveStuck();
  // The shared-memory ports this participant listens on (none over UDPv4 only).
  std::vector<int> ShmPortsListened() const;
  // The agents of the run on this host whose process has ended since the last call, by the
  // key of their participant (SameProcess with their writers), each once: the kernel released
  // the locks of all of its shared-memory ports, which a frozen or starved process keeps
  // (docs/PROTOCOL.md, "A process that ended"). Every agent's about every `every_s` (0.5 to
  // 1.5 times, at random, so that the processes of a run do not look at once), and
  // in between those of the `suspects` (those the target's roll call left out: one free look
  // of their locks is enough) at most every `suspects_every_s` (else empty); never
  // reports participants on other hosts or without shared memory, nor with
  // network.process_watch: false.
  // `suspects` is asked only when their look is due (it runs in the application's loop).
  // `waited_for` (in between too, as often as `suspects`): agents whose end is looked for
  // without another process having seen it, so two free looks in a row.
  std::vector<protocol::SenderKey> EndedAgents(double every_s,
                                               const std::function<std::set<AgentId>()>& suspects = nullptr,
                                               double suspects_every_s = 0.0,
                                               const std::function<std::set<AgentId>()>& waited_for = nullptr);
  // Those of them that a peer replaced under this process (it removed the port's segment and
  // made a new one, as Fast DDS 2.9.1 does with a port it takes for a dead process's) and
  // that stayed replaced for a whole port check (dds/shm_ports.hpp): every peer that opens
  // such a port from then on writes where this process does not read. Empty while it reads
  // them all. Checks at most once a second; only a new participant hears those peers again
  // (docs/FASTDDS_NOTES.md, "A port replaced under its listener").
  std::vector<int> PortsLost();
  // Samples this node's id_range readers dropped (keyed to an id outside the range).
  long DroppedByIdRange() const;
  // The readers that Wait() made anew since the last call, because one handed out the same
  // sample twice in a row: Fast DDS 2.9.1 lost track of it in the reader's history and
  // would hand it out for ever (docs/FASTDDS_NOTES.md, "A reader that hands out one sample
  // for ever"). The new reader gets the writers' histories again, as a late joiner does.
  std::vector<Topic> ReadersMadeAnew();
  // For tests: the next Wait() makes the reader of `topic` anew, as when it handed out a
  // sample twice.
  void MakeReaderAnewForTest(Topic topic);
  // Makes this participant's writers send every sample, as another vendor's or a hostile
  // writer does, instead of evaluating its peers' content filters first (a test tool's
  // attack must reach its targets). Before any writer or filtered reader.
  void StopWriterSideFiltering();
  // The readers this node's writer of `topic` currently matches (its own included), as
  // keys: the first 12 bytes name the reader's participant.
  std::set<protocol::SenderKey> MatchedReaderKeys(Topic topic) const;
  // How many writers currently match this node's reader of `topic` (its own included).
  int MatchedWriters(Topic topic) const;
  // How many readers currently match this node's writer of `topic` (its own included); for
  // ranges, its writers of every agent's ranges together (docs/PROTOCOL.md, "Ranges").
  int MatchedReaders(Topic topic) const;

  struct Impl;  // opaque: holds the Fast DDS entities

 private:
  std::unique_ptr<Impl> impl_;
};

// The environment variable that lists, comma-separated, the shared-memory ports this process
// listened on before it started again in place (docs/RUNNING.md, "Restarting in place"): a
// new participant takes no id whose ports it lists (docs/FASTDDS_NOTES.md, "A port replaced
// under its listener").
constexpr const char* kShmPortsUsedVariable = "DEIF_SHM_PORTS_USED";
// Its value for the next start: the ports it lists now and those of this process's newest
// participant.
std::string ShmPortsUsedSoFar();

// The timings a network of config.agents.count agents actually uses (dds/node.cpp): the
// configured ones, unless the N^2 liveliness, heartbeat and participant-announcement traffic
// would exceed what one busy host can carry; then a longer lease, fewer assertions, a longer
// heartbeat, a longer announcement period with a participant lease as many periods long.
struct Timings {
  double liveliness_lease_s = 0.0;
  int assertions_per_lease = 1;
  double heartbeat_period_s = 0.0;
  double participant_announcement_s = 0.0;
  double participant_lease_s = 0.0;
  // How long a lapse of a peer's contribution writer is held before it counts as a loss
  // (protocol::AgentProtocol::Options::peer_grace_s). The configured liveliness_grace_s, or
  // longer where that writer is renewed by its assertions alone (the tree exchange: it
  // writes nothing) and the budget made them rare: a lapse then counts only after
  // kRenewalsLostInARow renewals in a row went missing (docs/PROTOCOL.md, "Slow is not
  // gone").
  double peer_grace_s = 0.0;
};
Timings EffectiveTimings(const Config& config);
// The heartbeat period of a writer of `topic` [s]: a lost sample is repaired about one period
// later. EffectiveTimings' budgeted period, but, in real time, shorter for the writers with
// few readers each (the relays', and the target's writer of one agent's ranges over UDPv4),
// and within a budget of the target's own for the agents' state writers over UDPv4.
// per_agent_writer: one of the target's writers of ranges, one per agent.
double WriterHeartbeatS(Topic topic, const Config& config, bool per_agent_writer = false);
// How long a process's endpoint discovery may stay short of the participants it sees, unchanged,
// before it starts again in place with a new participant (protocol::DiscoveryWatch;
// docs/FASTDDS_NOTES.md, "Endpoint discovery that stops short"): matching under way at N = 64
// on 2 cores goes on for seconds between changes, so a few participant announcements more than
// that, at least 5 s; twice as long after each restart in place, so that a peer started late
// (the target of a run whose agents were started first) costs no more than a few.
double DiscoveryPatienceS(const Config& config, int restarts_in_place);

// How long a Discovery Server client may go on hearing nothing after it found the server again
// before it counts as forgotten by the server (protocol::SilenceWatch; docs/FASTDDS_NOTES.md,
// "Forgotten by the server"): a participant lease and two announcements. A host cut off for
// longer than the server's lease finds the server again at the heal and its peers within a
// second or two.
double ForgottenAfterS(const Timings& timings);

// Whether a Discovery Server client was forgotten by the server (docs/FASTDDS_NOTES.md,
// "Forgotten by the server"), from what the process takes from its node: the last sample, and
// the remote writers whose liveliness is alive.
class ServerForgetting {
 public:
  explicit ServerForgetting(const Timings& timings) : patience_s_(ForgottenAfterS(timings)) {}
  // Every event the process takes (Node::Wait), at now_s.
  void Note(const Event& event, double now_s);
  // Why the process counts as forgotten now, once per silence (protocol::SilenceWatch), or
  // nullopt. peers_listed: whether the processes it should hear from are listed up (the
  // target for an agent, agents for the target), asked only after a silence longer than the
  // patience, as is the server (each takes a lock: not at every wake-up of the loop). hears:
  // what it heard nothing of ("nothing", "no agent").
  std::optional<std::string> Forgotten(const Node& node, const std::function<bool()>& peers_listed,
                                       const std::string& hears, double now_s);
  // A process that may not start again any more goes on as it is: no more checks.
  void GiveUp() { watch_.GiveUp(); }

 private:
  double patience_s_;
  protocol::SilenceWatch watch_;
  std::set<protocol::SenderKey> alive_writers_;
};

// A steady_clock time point as seconds (the protocol's clock).
inline double ToSeconds(Clock::time_point t) {
  return std::chrono::duration<double>(t.time_since_epoch()).count();
}
inline Clock::time_point FromSeconds(double s) {
  return Clock::time_point(std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(s)));
}

// How long a secure participant whose handshake stalled at start may wait, at random, before
// it is created anew for the `restart`-th time, in a network of `agents` agents: 0.2 s per
// process and restart, at most 20 s. Participants re-created at the same moment are, for
// every other participant, new ones found at once, which is what stalls a handshake in Fast
// DDS 2.9.1: 16 secure agents started together began with every agent in 10 runs of 13 with
// the random wait, in none of 3 without it (docs/SECURITY.md, "Start-up").
double RestartWindowS(int restart, int agents);

// A random 64-bit token, different at every process start (never 0).
std::uint64_t RandomInstanceToken();

}  // namespace deif::dds
