#include "observer/live_model.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>

#include "common/config/initial_state.hpp"
#include "common/core/control_law.hpp"
#include "common/protocol/lapse_filter.hpp"

namespace deif::observer {

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
// A step that is not complete is finalised this long after it began (a state that never
// comes: an agent died within the step).
constexpr double kStepGiveUpS = 2.0;

// Positions to the micrometre, covariances and bounds to 6 significant digits: enough for
// the page, and a third of the bytes of 17 digits.
double Micro(double v) { return std::isfinite(v) ? std::round(v * 1e6) / 1e6 : v; }
double Sig6(double v) {
  if (!std::isfinite(v) || v == 0.0) return v;
  char buffer[32];
  std::snprintf(buffer, sizeof buffer, "%.6g", v);
  return std::strtod(buffer, nullptr);
}

bool Finite(const Vector2& v) { return std::isfinite(v.x()) && std::isfinite(v.y()); }
bool Finite(const Matrix2& m) { return m.allFinite(); }

nlohmann::json Xy(const Vector2& p) { return nlohmann::json::array({Micro(p.x()), Micro(p.y())}); }
nlohmann::json Cov(const Matrix2& c) {
  return nlohmann::json::array({Sig6(c(0, 0)), Sig6(c(0, 1)), Sig6(c(1, 1))});
}

std::string IdList(const std::vector<AgentId>& ids) {
  std::string out;
  for (std::size_t i = 0; i < ids.size(); ++i) {
    out += (i == 0 ? "" : i + 1 == ids.size() ? " and " : ", ") + std::to_string(ids[i]);
  }
  return out;
}

}  // namespace

LiveModel::LiveModel(const Config& config, protocol::RunToken run, const std::string& run_name,
                     ModelOptions options)
    : config_(config),
      run_(run),
      run_name_(run_name),
      options_(options),
      pcrlb_(config.filter.motion_model, InitialCovariance(config)) {
  for (AgentId id = 1; id <= config_.agents.count; ++id) agents_[id];
}

// ---------------------------------------------------------------------------------------
// Inputs

void LiveModel::OnTruth(const protocol::TruthMsg& msg, double now_s) {
  if (msg.run != run_) return Ignore("another run's truth", now_s);
  if (msg.step == -1) {  // the end-of-run signal (docs/PROTOCOL.md)
    if (!ended_) {
      ended_ = true;
      AddMark(now_s, "end", 0, "run over after step " + std::to_string(newest_step_));
      FinaliseSteps(now_s, true);
      FlushCounterMarks(now_s, true);
      Touch(now_s);
    }
    return;
  }
  if (msg.step < 1 || !Finite(msg.p_true) || !std::isfinite(msg.t_s)) {
    return Ignore("an invalid truth", now_s);
  }
  target_seen_ = true;
  truth_ = msg;
  while (!truth_trail_.empty() && truth_trail_.back().step >= msg.step) truth_trail_.pop_back();
  truth_trail_.push_back({msg.step, msg.p_true});
  while (static_cast<int>(truth_trail_.size()) > options_.trail_steps) truth_trail_.pop_front();
  if (msg.step > finalised_) {
    StepData& data = Step(msg.step, now_s);
    data.truth = msg.p_true;
    data.t_s = msg.t_s;
  }
  NoteStep(msg.step, now_s);
  FinaliseSteps(now_s, false);
  Touch(now_s);
}

void LiveModel::OnRange(const protocol::RangeMsg& msg, const protocol::SenderKey& from, double now_s) {
  if (msg.run != run_) return Ignore("another run's range", now_s);
  if (msg.agent_id < 1 || msg.agent_id > config_.agents.count || msg.step < 1 ||
      !Finite(msg.p_sensor)) {
    return Ignore("an invalid range", now_s);
  }
  // The target writes each agent's ranges with a writer of its own (docs/PROTOCOL.md,
  // "Ranges"): a new target is a new participant.
  if (!range_writer_ || !protocol::SameProcess(*range_writer_, from)) {
    if (range_writer_) {
      ++target_restarts_;
      AddMark(now_s, "target_restart", 0, "the target restarted (a new range writer)");
    }
    range_writer_ = from;
    target_live_ = true;
    target_seen_ = true;
    Touch(now_s);
  }
  if (msg.step > finalised_) {
    StepData& data = Step(msg.step, now_s);
    if (msg.measured) data.sensors[msg.agent_id] = msg.p_sensor;
    data.roll_call = msg.roll_call;
  }
  if (msg.step >= newest_roll_call_step_) {
    newest_roll_call_step_ = msg.step;
    newest_roll_call_ = msg.roll_call;
  }
  NoteStep(msg.step, now_s);
  FinaliseSteps(now_s, false);
}

void LiveModel::OnState(const protocol::StateMsg& msg, const protocol::SenderKey& from,
                        double written_unix_s, double now_s) {
  if (msg.run != run_) return Ignore("another run's state", now_s);
  if (msg.agent_id < 1 || msg.agent_id > config_.agents.count) {
    return Ignore("a state with an unknown agent id", now_s);
  }
  if (msg.step < 0 || !Finite(msg.position_m) || !Finite(msg.estimate_m) ||
      !Finite(msg.covariance) || !std::isfinite(msg.angle_rad)) {
    return Ignore("a state with non-finite numbers", now_s);
  }
  const AgentId id = msg.agent_id;
  Agent& a = agents_[id];
  bool newer = !a.seen || msg.step > a.state.step;
  if (!a.seen) {
    a.seen = true;
    a.writer = from;
    a.token = msg.instance_token;
    state_writers_[from] = id;
    live_unknown_.erase(from);
    a.live = true;  // first sight: neither a return nor a restart
    a.changed = true;
  } else if (from != a.writer) {
    if (a.live) {  // another process speaks for a live agent: not this agent's state
      return Ignore("a second writer claiming a live agent's id", now_s);
    }
    if (msg.instance_token != a.token) {
      ++a.restarts;
      AddMark(now_s, "restart", id, "agent " + std::to_string(id) + " restarted (a new process)");
      a.rejected_marked = a.dropped_marked = a.misses_marked = 0;
      a.trail.clear();
      newer = true;
    }
    a.writer = from;
    a.token = msg.instance_token;
    state_writers_[from] = id;
    a.live = true;  // a restart is marked as such, not as a return
    a.stale = false;
    a.changed = true;
  } else if (!a.live && newer) {
    SetLive(id, true, now_s);  // it writes again: its liveliness will follow
  }
  if (newer) {
    a.state = msg;
    a.state_rx_s = now_s;
    a.written_unix_s = written_unix_s;
    a.stale = false;
    if (msg.step >= 1) {
      while (!a.trail.empty() && a.trail.back().step >= msg.step) a.trail.pop_back();
      a.trail.push_back({msg.step, msg.position_m});
      while (static_cast<int>(a.trail.size()) > options_.trail_steps) a.trail.pop_front();
    }
    a.changed = true;
  }
  if (msg.step >= 1 && msg.step > finalised_) {
    StepData& data = Step(msg.step, now_s);
    data.estimates[id] = {msg.estimate_m, msg.covariance};
    data.members[id] = msg.alive;
  }
  if (msg.step >= 1) NoteStep(msg.step, now_s);
  FinaliseSteps(now_s, false);
  FlushCounterMarks(now_s, false);
  Touch(now_s);
}

void LiveModel::OnProcessEnded(const protocol::SenderKey& participant, double now_s) {
  std::vector<AgentId> ended;
  for (const auto& [writer, id] : state_writers_) {
    if (protocol::SameProcess(writer, participant) && agents_[id].writer == writer) ended.push_back(id);
  }
  for (AgentId id : ended) SetLive(id, false, now_s, protocol::kProcessEnded);
  if (!ended.empty()) Touch(now_s);
}

std::set<AgentId> LiveModel::LiveOutOfRollCall() const {
  std::set<AgentId> out;
  if (newest_roll_call_step_ == 0) return out;
  for (const auto& [id, a] : agents_) {
    if (a.seen && a.live && std::find(newest_roll_call_.begin(), newest_roll_call_.end(), id) == newest_roll_call_.end()) {
      out.insert(id);
    }
  }
  return out;
}

void LiveModel::OnLiveliness(WriterKind kind, const protocol::SenderKey& writer, bool alive,
                             double now_s) {
  if (kind == WriterKind::kState) {
    auto it = state_writers_.find(writer);
    if (it == state_writers_.end()) {
      if (alive) {
        live_unknown_.insert(writer);
      } else {
        live_unknown_.erase(writer);
      }
      return;
    }
    if (agents_[it->second].writer != writer) return;  // a writer of an earlier process
    SetLive(it->second, alive, now_s);
    Touch(now_s);
  } else if (kind == WriterKind::kRange) {
    if (range_writer_ && !protocol::SameProcess(*range_writer_, writer)) return;  // not the current target
    if (alive == target_live_) return;
    target_live_ = alive;
    if (target_seen_ && !alive && newest_step_ >= config_.scenario.steps) {
      AddMark(now_s, "done", 0, "the target finished the run");
    } else if (target_seen_) {
      AddMark(now_s, alive ? "target_back" : "target_lost", 0,
              alive ? "the target is back" : "the target lost (liveliness)");
    }
    Touch(now_s);
  }
}

void LiveModel::OnTimer(double now_s) {
  for (auto& [id, a] : agents_) {
    if (!a.seen || !a.live) continue;
    const bool stale = now_s - a.state_rx_s > options_.stale_after_s && newest_step_ > a.state.step;
    if (stale != a.stale) {
      a.stale = stale;
      a.changed = true;
      Touch(now_s);
    }
  }
  FinaliseSteps(now_s, false, true);
  FlushCounterMarks(now_s, false);
}

// ---------------------------------------------------------------------------------------
// Bookkeeping

void LiveModel::Touch(double now_s) {
  if (!dirty_) dirty_since_s_ = now_s;
  dirty_ = true;
}

void LiveModel::AddMark(double now_s, const std::string& kind, AgentId agent, const std::string& text) {
  marks_.push_back({next_mark_id_++, newest_step_, now_s, kind, agent, text});
  while (static_cast<int>(marks_.size()) > options_.marks_kept) marks_.pop_front();
  Touch(now_s);
}

void LiveModel::OnUnauthorised(AgentId claimed, double now_s) {
  (void)claimed;
  Ignore("a state its writer may not write (not_authorised)", now_s);
}

void LiveModel::Ignore(const std::string& reason, double now_s) {
  ++ignored_;
  if (ignored_marked_.insert(reason).second) {
    AddMark(now_s, "ignored", 0, "ignored " + reason + " (further ones are only counted)");
  }
}

void LiveModel::NoteStep(StepIndex step, double now_s) {
  if (step > newest_step_) {
    newest_step_ = step;
    newest_step_s_ = now_s;
  }
}

LiveModel::StepData& LiveModel::Step(StepIndex step, double now_s) {
  auto [it, inserted] = steps_.try_emplace(step);
  if (inserted) it->second.first_seen_s = now_s;
  return it->second;
}

void LiveModel::SetLive(AgentId id, bool live, double now_s, const char* why) {
  Agent& a = agents_[id];
  if (a.live == live) return;
  a.live = live;
  a.stale = false;
  a.changed = true;
  const std::string who = "agent " + std::to_string(id);
  if (!live && a.state.step >= config_.scenario.steps) {  // it wrote the last step and ended
    AddMark(now_s, "done", id, who + " finished the run");
    return;
  }
  auto& recent = live ? recent_returns_ : recent_losses_;
  recent.push_back({now_s, id});
  while (!recent.empty() && now_s - recent.front().first > options_.together_s) recent.pop_front();
  AddMark(now_s, live ? "back" : "lost", id, who + (live ? std::string(" back") : " lost (" + std::string(why) + ")"));
  double& last = live ? last_heal_mark_s_ : last_partition_mark_s_;
  if (recent.size() >= 2 && now_s - last > options_.together_s) {
    std::vector<AgentId> ids;
    for (const auto& entry : recent) ids.push_back(entry.second);
    std::sort(ids.begin(), ids.end());
    ids.erase(std::unique(ids.begin(), ids.end()), ids.end());
    if (ids.size() >= 2) {
      last = now_s;
      AddMark(now_s, live ? "heal" : "partition", 0,
              live ? "agents " + IdList(ids) + " back together: a partition healed?"
                   : "agents " + IdList(ids) + " lost together: a partition or a host down?");
    }
  }
}

void LiveModel::FlushCounterMarks(double now_s, bool force) {
  for (auto& [id, a] : agents_) {
    if (!a.seen) continue;
    const std::int64_t rejected = a.state.rejected - a.rejected_marked;
    const std::int64_t dropped = a.state.dropped - a.dropped_marked;
    const std::int64_t misses = a.state.deadline_misses - a.misses_marked;
    if (rejected <= 0 && dropped <= 0 && misses <= 0) continue;
    if (!force && now_s - a.last_counter_mark_s < options_.counter_mark_interval_s) continue;
    const std::string who = "agent " + std::to_string(id);
    if (rejected > 0) {
      AddMark(now_s, "rejected", id,
              who + " rejected " + std::to_string(rejected) + " invalid message(s) (" +
                  std::to_string(a.state.rejected) + " in all)");
    }
    if (dropped > 0) {
      AddMark(now_s, "dropped", id,
              who + " dropped " + std::to_string(dropped) + " unusable message(s) (" +
                  std::to_string(a.state.dropped) + " in all)");
    }
    if (misses > 0) {
      AddMark(now_s, "misses", id,
              who + " finished " + std::to_string(misses) + " step(s) incomplete (" +
                  std::to_string(a.state.deadline_misses) + " in all)");
    }
    a.rejected_marked = std::max(a.rejected_marked, a.state.rejected);
    a.dropped_marked = std::max(a.dropped_marked, a.state.dropped);
    a.misses_marked = std::max(a.misses_marked, a.state.deadline_misses);
    a.last_counter_mark_s = now_s;
  }
}

bool LiveModel::StepComplete(StepIndex, const StepData& data) const {
  if (!data.truth || !data.roll_call) return false;
  for (AgentId id : *data.roll_call) {
    if (data.sensors.count(id) == 0 || data.estimates.count(id) == 0) return false;
  }
  return true;
}

void LiveModel::FinaliseSteps(double now_s, bool all_old, bool by_age) {
  while (!steps_.empty()) {
    auto it = steps_.begin();
    const StepIndex k = it->first;
    // A step two behind the newest, or too old, is given up only from OnTimer: samples of
    // one batch come topic by topic (all truths, then all ranges), so a later step's truth
    // can be read before this step's ranges.
    const bool old = by_age && (k + 2 <= newest_step_ || now_s - it->second.first_seen_s > kStepGiveUpS);
    const bool done = all_old || old || StepComplete(k, it->second);
    if (!done) return;
    Finalise(k, it->second);
    finalised_ = k;
    steps_.erase(it);
    Touch(now_s);
  }
}

void LiveModel::Finalise(StepIndex step, StepData& data) {
  if (!data.truth && data.estimates.empty()) return;
  SeriesPoint p;
  p.step = step;
  p.t_s = data.truth ? data.t_s : static_cast<double>(step) * config_.scenario.dt_s;
  std::vector<SensorGeometry> sensors;
  for (const auto& [id, position] : data.sensors) {
    sensors.push_back({position, config_.target.range_noise_variance_m2});
  }
  p.pcrlb_m = p.ratio = p.error_m = p.max_error_m = p.sigma_m = kNaN;
  if (data.truth) {
    // As deif_sim --evaluate: a step without truth is skipped, one without sensors predicts.
    if (!pcrlb_from_step_) pcrlb_from_step_ = step;
    pcrlb_.Step(*data.truth, sensors, config_.sensing);
    p.pcrlb_m = std::sqrt(pcrlb_.PositionBound().trace());
    if (!sensors.empty()) {
      p.ratio = OptimalityRatio(FisherInformation(sensors, *data.truth, config_.sensing));
    }
  }
  if (!data.estimates.empty()) {
    const auto& [ref_id, ref] = *data.estimates.begin();  // the lowest id
    p.agent = ref_id;
    p.sigma_m = std::sqrt(ref.second.trace());
    if (data.truth) {
      p.error_m = (ref.first - *data.truth).norm();
      p.max_error_m = 0.0;
      for (const auto& [id, e] : data.estimates) {
        p.max_error_m = std::max(p.max_error_m, (e.first - *data.truth).norm());
      }
    }
  }
  p.alive = AliveCount();
  series_.push_back(p);
  while (static_cast<int>(series_.size()) > options_.series_steps) series_.pop_front();

  // Membership as the agents see it: live agents that disagree on how many are alive see
  // different networks (a partition, or a loss not yet noticed everywhere).
  std::set<int> views;
  for (const auto& [id, members] : data.members) {
    if (agents_[id].live) views.insert(members);
  }
  const bool differ = views.size() >= 2;
  if (differ != views_differ_) {
    views_differ_ = differ;
    std::string text = differ ? "the agents disagree on who is alive:"
                              : "the agents agree again on who is alive";
    if (differ) {
      for (const auto& [id, members] : data.members) {
        text += " " + std::to_string(id) + " sees " + std::to_string(members) + ",";
      }
      text.pop_back();
    }
    AddMark(newest_step_s_, "views", 0, text);
  }
}

// ---------------------------------------------------------------------------------------
// Outputs

int LiveModel::AliveCount() const {
  int n = 0;
  for (const auto& [id, a] : agents_) n += a.seen && a.live ? 1 : 0;
  return n;
}

std::string LiveModel::StatusOf(AgentId id) const {
  auto it = agents_.find(id);
  if (it == agents_.end() || !it->second.seen) return "never";
  if (!it->second.live) return it->second.state.step >= config_.scenario.steps ? "done" : "lost";
  return it->second.stale ? "stale" : "alive";
}

bool LiveModel::NewestStepHasStates() const {
  for (const auto& [id, a] : agents_) {
    if (a.seen && a.live && !a.stale && a.state.step < newest_step_) return false;
  }
  return true;
}

bool LiveModel::UpdateDue(double now_s) const {
  if (!dirty_ || now_s - last_update_s_ < options_.min_update_interval_s) return false;
  return NewestStepHasStates() || now_s - dirty_since_s_ >= options_.settle_s;
}

std::optional<double> LiveModel::NextUpdateTime(double now_s) const {
  if (!dirty_) return std::nullopt;
  const double earliest = last_update_s_ + options_.min_update_interval_s;
  const double settled = NewestStepHasStates() ? now_s : dirty_since_s_ + options_.settle_s;
  return std::max(earliest, settled);
}

nlohmann::json LiveModel::AgentJson(AgentId id, const Agent& a, bool full_trail) const {
  nlohmann::json j = {{"id", id}, {"status", StatusOf(id)}};
  if (!a.seen) return j;
  const protocol::StateMsg& s = a.state;
  j["step"] = s.step;
  j["pos"] = Xy(s.position_m);
  j["angle"] = Micro(s.angle_rad);
  j["est"] = Xy(s.estimate_m);
  j["cov"] = Cov(s.covariance);
  j["members"] = s.alive;
  j["fused"] = s.fused;
  j["complete"] = s.complete;
  j["misses"] = s.deadline_misses;
  j["rejected"] = s.rejected;
  j["dropped"] = s.dropped;
  j["restarts"] = a.restarts;
  j["written"] = a.written_unix_s;
  nlohmann::json trail = nlohmann::json::array();
  for (const TrailPoint& t : a.trail) {
    if (full_trail || t.step > a.trail_sent_step) {
      trail.push_back({t.step, Micro(t.p.x()), Micro(t.p.y())});
    }
  }
  j[full_trail ? "trail" : "trail_add"] = std::move(trail);
  return j;
}

nlohmann::json LiveModel::RingJson() const {
  std::vector<RingMember> members;
  for (const auto& [id, a] : agents_) {
    if (a.seen && a.live) members.push_back({id, a.state.angle_rad});
  }
  const std::vector<RingMember> ring = FormRing(members);
  nlohmann::json ids = nlohmann::json::array();
  nlohmann::json gaps = nlohmann::json::array();
  for (const RingMember& m : ring) ids.push_back(m.agent_id);
  if (ring.size() >= 2) {
    for (double g : RingGaps(ring)) gaps.push_back(Micro(g));
  }
  const int n = static_cast<int>(ring.size());
  return {{"n", n},
          {"members", ids},
          {"gaps", gaps},
          {"optimal", Micro(OptimalGapRad(n))},
          {"max_error", Micro(MaxGapError(ring))}};
}

nlohmann::json LiveModel::SeriesJson(StepIndex after_step) const {
  nlohmann::json steps = nlohmann::json::array(), t = nlohmann::json::array(),
                 error = nlohmann::json::array(), max_error = nlohmann::json::array(),
                 sigma = nlohmann::json::array(), pcrlb = nlohmann::json::array(),
                 ratio = nlohmann::json::array(), alive = nlohmann::json::array();
  for (const SeriesPoint& p : series_) {
    if (p.step <= after_step) continue;
    steps.push_back(p.step);
    t.push_back(Micro(p.t_s));
    error.push_back(Sig6(p.error_m));
    max_error.push_back(Sig6(p.max_error_m));
    sigma.push_back(Sig6(p.sigma_m));
    pcrlb.push_back(Sig6(p.pcrlb_m));
    ratio.push_back(Sig6(p.ratio));
    alive.push_back(p.alive);
  }
  return {{"step", steps},   {"t", t},         {"error", error}, {"max_error", max_error},
          {"sigma", sigma}, {"pcrlb", pcrlb}, {"ratio", ratio}, {"alive", alive}};
}

nlohmann::json LiveModel::CommonJson(double now_s) const {
  nlohmann::json j;
  j["step"] = newest_step_;
  j["t"] = Micro(now_s);
  j["ended"] = ended_;
  j["alive"] = AliveCount();
  j["agents_count"] = config_.agents.count;
  j["ignored"] = ignored_;
  j["target"] = {{"seen", target_seen_}, {"alive", target_live_}, {"restarts", target_restarts_}};
  if (truth_) {
    j["truth"] = {{"step", truth_->step}, {"t", Micro(truth_->t_s)}, {"pos", Xy(truth_->p_true)}};
  } else {
    j["truth"] = nullptr;
  }
  // The estimate shown: the lowest-id live agent's (every agent fuses the same sum).
  j["estimate"] = nullptr;
  for (const auto& [id, a] : agents_) {
    if (a.seen && a.live && a.state.step >= 1) {
      j["estimate"] = {{"agent", id},
                       {"step", a.state.step},
                       {"pos", Xy(a.state.estimate_m)},
                       {"cov", Cov(a.state.covariance)}};
      break;
    }
  }
  j["ring"] = RingJson();
  return j;
}

std::optional<nlohmann::json> LiveModel::TakeUpdate(double now_s) {
  if (!dirty_) return std::nullopt;
  nlohmann::json j = CommonJson(now_s);
  j["type"] = "update";
  nlohmann::json agents = nlohmann::json::array();
  for (auto& [id, a] : agents_) {
    if (!a.changed) continue;
    agents.push_back(AgentJson(id, a, false));
    a.changed = false;
    if (!a.trail.empty()) a.trail_sent_step = a.trail.back().step;
  }
  j["agents"] = std::move(agents);
  nlohmann::json truth_add = nlohmann::json::array();
  for (const TrailPoint& t : truth_trail_) {
    if (t.step > truth_sent_step_) truth_add.push_back({t.step, Micro(t.p.x()), Micro(t.p.y())});
  }
  if (!truth_trail_.empty()) truth_sent_step_ = truth_trail_.back().step;
  j["truth_add"] = std::move(truth_add);
  j["series"] = SeriesJson(series_sent_step_);
  if (!series_.empty()) series_sent_step_ = series_.back().step;
  nlohmann::json marks = nlohmann::json::array();
  for (const Mark& m : marks_) {
    if (m.id <= marks_sent_up_to_) continue;
    marks.push_back({{"id", m.id}, {"step", m.step}, {"t", Micro(m.t_s)}, {"kind", m.kind},
                     {"agent", m.agent}, {"text", m.text}});
    marks_sent_up_to_ = m.id;
  }
  j["marks"] = std::move(marks);
  dirty_ = false;
  last_update_s_ = now_s;
  return j;
}

nlohmann::json LiveModel::Snapshot(double now_s) const {
  nlohmann::json j = CommonJson(now_s);
  j["type"] = "snapshot";
  j["run"] = run_name_;
  j["config"] = {{"agents", config_.agents.count},
                 {"dt_s", config_.scenario.dt_s},
                 {"steps", config_.scenario.steps},
                 {"mode", config_.scenario.mode == StepMode::kRealTime ? "realtime" : "lockstep"},
                 {"period_s", config_.scenario.period_s},
                 {"radius_m", config_.agents.radius_m},
                 {"lease_s", config_.network.liveliness_lease_s},
                 {"trail_steps", options_.trail_steps},
                 {"domain", config_.network.domain_id},
                 {"ros2_naming", config_.network.ros2_naming}};
  nlohmann::json agents = nlohmann::json::array();
  for (const auto& [id, a] : agents_) agents.push_back(AgentJson(id, a, true));
  j["agents"] = std::move(agents);
  nlohmann::json trail = nlohmann::json::array();
  for (const TrailPoint& t : truth_trail_) trail.push_back({t.step, Micro(t.p.x()), Micro(t.p.y())});
  j["truth_trail"] = std::move(trail);
  j["series"] = SeriesJson(-1);
  j["pcrlb_from_step"] =
      pcrlb_from_step_ ? nlohmann::json(*pcrlb_from_step_) : nlohmann::json(nullptr);
  nlohmann::json marks = nlohmann::json::array();
  for (const Mark& m : marks_) {
    marks.push_back({{"id", m.id}, {"step", m.step}, {"t", Micro(m.t_s)}, {"kind", m.kind},
                     {"agent", m.agent}, {"text", m.text}});
  }
  j["marks"] = std::move(marks);
  return j;
}

}  // namespace deif::observer
