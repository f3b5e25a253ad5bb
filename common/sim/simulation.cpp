// The in-process simulation: every process of a run as a protocol object, the network in
// between simulated (sim_network.hpp), time virtual. docs/PROTOCOL.md explains the protocol
// both this and the DDS processes run.
#include "common/sim/simulation.hpp"

#include <algorithm>
#include <filesystem>
#include <limits>
#include <memory>
#include <optional>
#include <set>
#include <type_traits>

#include "common/core/random.hpp"
#include "common/protocol/target_protocol.hpp"

namespace deif::sim {

namespace {

using protocol::AgentAction;
using protocol::AgentProtocol;
using protocol::TargetAction;
using protocol::TargetProtocol;
namespace agent_action = protocol::agent_action;
namespace target_action = protocol::target_action;

constexpr double kNever = std::numeric_limits<double>::infinity();

enum class NodeState { kRunning, kFrozen, kDead, kFinished };

struct AgentNode {
  std::unique_ptr<AgentProtocol> protocol;
  std::optional<AgentCsv> csv;
  NodeState state = NodeState::kRunning;
};

class Simulation {
 public:
  Simulation(const Config& config, const SimulationOptions& options)
      : config_(config),
        options_(options),
        run_(protocol::RunTokenOf("sim")),
        network_(config, MixBits(config.scenario.seed ^ 0x6e6574776f726bull)),  // "network"
        agents_(static_cast<std::size_t>(config.agents.count) + 1),
        timer_of_(static_cast<std::size_t>(config.agents.count) + 1, kNever) {
    if (options_.drop_filter) network_.SetDropFilter(options_.drop_filter);
    if (!options_.out_dir.empty()) {
      const std::filesystem::path dir(options_.out_dir);
      std::filesystem::create_directories(dir);
      target_csv_.emplace((dir / kTargetCsvSchema.file_name).string());
      ranges_csv_.emplace((dir / kRangesCsvSchema.file_name).string());
    }
    for (AgentId id = 1; id <= config.agents.count; ++id) {
      AgentNode& node = agents_[static_cast<std::size_t>(id)];
      AgentProtocol::Options agent_options;
      agent_options.run = run_;
      agent_options.instance_token = static_cast<std::uint64_t>(id);
      node.protocol = std::make_unique<AgentProtocol>(config, id, agent_options);
      if (!options_.out_dir.empty()) {
        node.csv.emplace((std::filesystem::path(options_.out_dir) / AgentCsvName(id)).string());
      }
    }
    target_ = MakeTarget(std::nullopt);
  }

  SimulationResult Run() {
    for (AgentId id = 1; id <= config_.agents.count; ++id) {
      Agent(id).protocol->Start(now_);
      DrainAgent(id);
    }
    target_->Start(now_);
    DrainTarget();
    last_progress_s_ = now_;
    const double stall_s = 2.0 * config_.network.start_timeout_s + config_.network.step_timeout_s +
                           10.0 * config_.network.liveliness_lease_s;
    while (!Done()) {
      const double t_net = network_.NextEventTime().value_or(kNever);
      const double t_timer = timers_.empty() ? kNever : timers_.begin()->first;
      const double t = std::min(t_net, t_timer);
      if (t == kNever || t - last_progress_s_ > stall_s) break;  // nothing can move any more
      now_ = std::max(now_, t);
      for (const NetworkEvent& event : network_.PopDue(now_)) Dispatch(event);
      while (!timers_.empty() && timers_.begin()->first <= now_) {
        const NodeId node = timers_.begin()->second;
        timers_.erase(timers_.begin());
        timer_of_[static_cast<std::size_t>(node)] = kNever;
        if (node == kTargetNode) {
          if (target_) {
            target_->OnTimer(now_);
            DrainTarget();
          }
        } else if (Agent(node).state == NodeState::kRunning) {
          Agent(node).protocol->OnTimer(now_);
          DrainAgent(node);
        }
      }
      if (target_done_) ResumeFrozenAgents();
    }
    return Finish();
  }

 private:
  AgentNode& Agent(NodeId id) { return agents_[static_cast<std::size_t>(id)]; }

  std::unique_ptr<TargetProtocol> MakeTarget(std::optional<StepIndex> start_step) {
    TargetProtocol::Options target_options;
    target_options.run = run_;
    target_options.start_step = start_step;
    target_options.hold_for_faults = true;  // faults land on their exact step
    return std::make_unique<TargetProtocol>(config_, target_options);
  }

  bool Done() const {
    if (!target_done_) return false;
    for (AgentId id = 1; id <= config_.agents.count; ++id) {
      const NodeState state = agents_[static_cast<std::size_t>(id)].state;
      if (state == NodeState::kRunning || state == NodeState::kFrozen) return false;
    }
    return true;
  }

  void Dispatch(const NetworkEvent& event) {
    if (const auto* delivery = std::get_if<Delivery>(&event)) {
      if (delivery->to == kTargetNode) {
        if (!target_) return;
        if (const auto* state = std::get_if<protocol::StateMsg>(&delivery->message)) {
          target_->OnState(*state, delivery->writer, now_);
          DrainTarget();
        }
        return;
      }
      AgentNode& node = Agent(delivery->to);
      if (node.state != NodeState::kRunning) return;
      if (const auto* range = std::get_if<protocol::RangeMsg>(&delivery->message)) {
        node.protocol->OnRange(*range, delivery->writer, now_);
      } else if (const auto* c = std::get_if<protocol::ContributionMsg>(&delivery->message)) {
        node.protocol->OnContribution(*c, delivery->writer, now_);
      }
      DrainAgent(delivery->to);
      return;
    }
    const auto& change = std::get<LivelinessChange>(event);
    if (change.reader == kTargetNode) {
      if (!target_) return;
      target_->OnWriterLiveliness(change.writer, change.alive, now_);
      DrainTarget();
      return;
    }
    AgentNode& node = Agent(change.reader);
    if (node.state != NodeState::kRunning) return;
    node.protocol->OnWriterLiveliness(change.writer, change.alive, now_);
    DrainAgent(change.reader);
  }

  void RefreshTimer(NodeId node, std::optional<double> deadline) {
    double& current = timer_of_[static_cast<std::size_t>(node)];
    if (current != kNever) timers_.erase({current, node});
    current = deadline.value_or(kNever);
    if (current != kNever) timers_.insert({current, node});
  }

  void Log(const std::string& process, protocol::LogLevel level, const std::string& text) {
    if (options_.log) options_.log(process, level, text);
  }

  void DrainAgent(AgentId id) {
    AgentNode& node = Agent(id);
    const std::string name = "agent-" + std::to_string(id);
    for (AgentAction& action : node.protocol->TakeActions()) {
      std::visit(
          [&](auto& a) {
            using A = std::decay_t<decltype(a)>;
            if constexpr (std::is_same_v<A, agent_action::PublishContribution>) {
              network_.Send(now_, id, a.msg);
            } else if constexpr (std::is_same_v<A, agent_action::PublishState>) {
              network_.Send(now_, id, a.msg);
            } else if constexpr (std::is_same_v<A, agent_action::WriteRow>) {
              if (node.csv) node.csv->Write(a.row);
              run_data_.agents[id].push_back(a.row);
              last_progress_s_ = now_;
            } else if constexpr (std::is_same_v<A, agent_action::Log>) {
              Log(name, a.level, a.text);
            } else if constexpr (std::is_same_v<A, agent_action::Finish>) {
              exit_codes_[name] = a.exit_code;
              node.state = NodeState::kFinished;
              Log(name, protocol::LogLevel::kInfo, a.reason);
            }
          },
          action);
    }
    RefreshTimer(id, node.state == NodeState::kRunning ? node.protocol->NextDeadline() : std::nullopt);
  }

  void DrainTarget() {
    for (bool again = true; again && target_;) {
      again = false;
      std::vector<TargetAction> actions = target_->TakeActions();
      for (TargetAction& action : actions) {
        if (const auto* range = std::get_if<target_action::PublishRange>(&action)) {
          network_.SetStep(range->msg.step, now_);
          network_.Send(now_, kTargetNode, range->msg);
        } else if (const auto* truth = std::get_if<target_action::WriteTruthRow>(&action)) {
          if (target_csv_) target_csv_->Write(truth->row);
          run_data_.truth.push_back(truth->row);
          last_progress_s_ = now_;
        } else if (const auto* row = std::get_if<target_action::WriteRangeRow>(&action)) {
          if (ranges_csv_) ranges_csv_->Write(row->row);
          run_data_.ranges.push_back(row->row);
        } else if (const auto* hold = std::get_if<target_action::Hold>(&action)) {
          if (ApplyFaults(hold->step)) {
            again = true;  // a new target: what the old one meant to do next is void
            break;
          }
          if (config_.scenario.mode == StepMode::kLockStep) {
            target_->OnGo(hold->step, now_);
            again = true;
          }
        } else if (const auto* log = std::get_if<target_action::Log>(&action)) {
          Log("target", log->level, log->text);
        } else if (const auto* finish = std::get_if<target_action::Finish>(&action)) {
          exit_codes_["target"] = finish->exit_code;
          target_done_ = true;
          Log("target", protocol::LogLevel::kInfo, finish->reason);
        }
      }
    }
    RefreshTimer(kTargetNode, target_ && !target_done_ ? target_->NextDeadline() : std::nullopt);
  }

  // Applies the faults of `step` (once each). Returns true when the target was replaced.
  bool ApplyFaults(StepIndex step) {
    bool restarted = false;
    for (std::size_t i = 0; i < config_.faults.size(); ++i) {
      const FaultConfig& fault = config_.faults[i];
      if (fault.step != step || !applied_.insert(i).second) continue;
      if (fault.action == FaultAction::kRestartTarget) {
        network_.Restart(kTargetNode, now_);
        target_ = MakeTarget(step);
        target_->Start(now_);
        restarted = true;
        continue;
      }
      AgentNode& node = Agent(fault.agent_id);
      const std::string name = "agent-" + std::to_string(fault.agent_id);
      switch (fault.action) {
        case FaultAction::kKill:
          network_.Kill(fault.agent_id, now_);
          node.state = NodeState::kDead;
          exit_codes_[name] = -9;  // SIGKILL, as a process would report it
          RefreshTimer(fault.agent_id, std::nullopt);
          break;
        case FaultAction::kStop:
          network_.Freeze(fault.agent_id, now_);
          node.state = NodeState::kFrozen;
          RefreshTimer(fault.agent_id, std::nullopt);
          break;
        case FaultAction::kCont:
          Resume(fault.agent_id);
          break;
        case FaultAction::kRestartTarget:
          break;
      }
    }
    return restarted;
  }

  void Resume(AgentId id) {
    AgentNode& node = Agent(id);
    if (node.state != NodeState::kFrozen) return;
    network_.Resume(id, now_);
    node.state = NodeState::kRunning;
    node.protocol->OnTimer(now_);
    DrainAgent(id);
  }

  // At the end of the run, a frozen agent is resumed (as the launcher does) to finish.
  void ResumeFrozenAgents() {
    for (AgentId id = 1; id <= config_.agents.count; ++id) {
      if (Agent(id).state == NodeState::kFrozen) Resume(id);
    }
  }

  SimulationResult Finish() {
    SimulationResult result;
    for (AgentId id = 1; id <= config_.agents.count; ++id) {
      AgentNode& node = Agent(id);
      result.counters[id] = node.protocol->counters();
      const std::string name = "agent-" + std::to_string(id);
      if (exit_codes_.count(name) == 0) exit_codes_[name] = protocol::kExitRuntimeError;  // stuck
    }
    if (exit_codes_.count("target") == 0) exit_codes_["target"] = protocol::kExitRuntimeError;
    result.metrics = EvaluateRun(config_, run_data_);
    if (!options_.out_dir.empty()) {
      WriteMetricsCsv((std::filesystem::path(options_.out_dir) / "metrics.csv").string(),
                      result.metrics);
    }
    result.run = std::move(run_data_);
    result.exit_codes = exit_codes_;
    result.messages_sent = network_.sent();
    result.messages_lost_first_try = network_.lost_first_try();
    result.virtual_time_s = now_;
    return result;
  }

  const Config& config_;
  const SimulationOptions& options_;
  const protocol::RunToken run_;
  SimNetwork network_;
  std::vector<AgentNode> agents_;
  std::unique_ptr<TargetProtocol> target_;
  bool target_done_ = false;
  std::optional<TargetCsv> target_csv_;
  std::optional<RangesCsv> ranges_csv_;
  std::set<std::pair<double, NodeId>> timers_;
  std::vector<double> timer_of_;
  std::set<std::size_t> applied_;
  std::map<std::string, int> exit_codes_;
  RunData run_data_;
  double now_ = 0.0;
  double last_progress_s_ = 0.0;
};

}  // namespace

SimulationResult RunSimulation(const Config& config, const SimulationOptions& options) {
  Simulation simulation(config, options);
  return simulation.Run();
}

}  // namespace deif::sim
