// deif_observer: a passive participant of a run that serves a live page (docs/LIVE.md).
//   deif_observer --config FILE [--run NAME] [--port P] [--bind ADDRESS] [--url-host HOST]
//                 [--out DIR] [--set K=V] [--domain D] [--log-dir DIR] [--observer-id M]
// It reads deif/truth, deif/range and deif/agent_state and creates no writer (dds::Node's
// MakePassive), so it cannot change a run. The first line on stdout is the page's URL,
// "deif_observer: http://HOST:PORT/". With --out it writes DIR/observer.csv (the figures
// per step) and DIR/observer_marks.csv (every mark) as it goes, and DIR/observer_latency.csv:
// for each agent state the page got, the time from the agent's write (the DDS source
// timestamp) to the update that carried it leaving for the page (one host's clock).
// Exit codes: 0 stopped by SIGINT/SIGTERM, 1 runtime error (e.g. the port is taken), 2 bad
// command line or config.
#include <arpa/inet.h>
#include <ifaddrs.h>
#include <net/if.h>
#include <netinet/in.h>
#include <sys/resource.h>

#include <atomic>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <iterator>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>

#include <CLI/CLI.hpp>

#include "common/artefacts/artefacts.hpp"
#include "dds/application.hpp"
#include "dds/node.hpp"
#include "observer/live_model.hpp"
#include "observer/live_server.hpp"
#include "observer/page.hpp"

namespace deif::observer {
namespace {

struct ObserverOptions {
  int port = 0;
  std::string bind = "0.0.0.0";
  std::string url_host;
  int trail_steps = 200;
  int nice = 0;
  int observer_id = 1;
};

// The host part of the URL to print: the bind address, or for a wildcard bind the first
// IPv4 address of an interface that is up and not the loopback (what another machine, or
// the root namespace for a namespace host, can reach), else 127.0.0.1.
std::string UrlHost(const ObserverOptions& options) {
  if (!options.url_host.empty()) return options.url_host;
  if (options.bind != "0.0.0.0" && options.bind != "::" && !options.bind.empty()) return options.bind;
  std::string found = "127.0.0.1";
  ifaddrs* list = nullptr;
  if (getifaddrs(&list) != 0) return found;
  for (ifaddrs* i = list; i != nullptr; i = i->ifa_next) {
    if (i->ifa_addr == nullptr || i->ifa_addr->sa_family != AF_INET) continue;
    if ((i->ifa_flags & IFF_UP) == 0 || (i->ifa_flags & IFF_LOOPBACK) != 0) continue;
    char text[INET_ADDRSTRLEN] = {};
    const auto* in = reinterpret_cast<const sockaddr_in*>(i->ifa_addr);
    if (inet_ntop(AF_INET, &in->sin_addr, text, sizeof text) != nullptr) {
      found = text;
      break;
    }
  }
  freeifaddrs(list);
  return found;
}

double UnixNow() {
  timespec ts{};
  clock_gettime(CLOCK_REALTIME, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

std::string Cell(double v) { return std::isfinite(v) ? FormatDouble(v) : ""; }

std::string Quoted(const std::string& text) {
  std::string out = "\"";
  for (char c : text) out += c == '"' ? std::string("\"\"") : std::string(1, c);
  return out + "\"";
}

class Observer : public dds::Application {
 public:
  Observer(dds::ProcessContext& context, const ObserverOptions& options)
      : context_(context),
        options_(options),
        // With DDS Security its identity is observer-<M> (docs/CONFIG.md, network.security.dir).
        node_(context.config, "observer-" + std::to_string(options.observer_id), context.run_name),
        model_(context.config, protocol::RunTokenOf(context.run_name), context.run_name,
               ModelFromOptions(options)),
        server_(PageHtml(), [this] {
          std::lock_guard<std::mutex> lock(mutex_);
          return std::make_pair(model_.Snapshot(Now()).dump(), server_.LastSeq());
        }) {
    node_.MakePassive();  // no writer, ever: this process cannot change the run
    node_.AddReader({dds::Topic::kTruth, {}});
    node_.AddReader({dds::Topic::kRange, {}});
    node_.AddReader({dds::Topic::kAgentState, {}});
  }

  int Run() override {
    if (options_.nice != 0 && setpriority(PRIO_PROCESS, 0, options_.nice) != 0) {
      context_.log->warn("cannot set the nice value to {}", options_.nice);
    }
    const int port = server_.Start(options_.bind, options_.port);
    std::printf("deif_observer: http://%s:%d/\n", UrlHost(options_).c_str(), port);
    std::fflush(stdout);
    context_.log->info("observer up: run '{}', domain {}, page on {}:{}", context_.run_name,
                       context_.config.network.domain_id, options_.bind, port);
    OpenFiles();
    while (!stop_.load()) {
      auto deadline = dds::Clock::now() + std::chrono::milliseconds(100);
      {
        std::lock_guard<std::mutex> lock(mutex_);
        if (const auto next = model_.NextUpdateTime(Now())) {
          deadline = std::min(deadline, start_ + std::chrono::duration_cast<dds::Clock::duration>(
                                                     std::chrono::duration<double>(*next)));
        }
      }
      const std::vector<dds::Event> events = node_.Wait(deadline);
      std::lock_guard<std::mutex> lock(mutex_);
      const double now = Now();
      for (const dds::Event& event : events) Dispatch(event, now);
      dds::LogReadersMadeAnew(node_, *context_.log);
      for (const protocol::SenderKey& ended : node_.EndedAgents(0.1, [this] { return model_.LiveOutOfRollCall(); }, 0.02)) {
        model_.OnProcessEnded(ended, now);
      }
      model_.OnTimer(now);
      if (model_.UpdateDue(now)) {
        if (auto update = model_.TakeUpdate(now)) {
          const double sent = UnixNow();
          (*update)["sent"] = sent;
          server_.Publish(update->dump());
          NoteLatencies(*update, sent);
        }
      }
      WriteFiles();
    }
    server_.Stop();
    std::lock_guard<std::mutex> lock(mutex_);
    WriteFiles();
    context_.log->info("stopped at step {}; {} sample(s) ignored", model_.newest_step(), model_.ignored());
    return 0;
  }

  void Stop() override {
    stop_.store(true);
    node_.Wake();
  }

 private:
  static ModelOptions ModelFromOptions(const ObserverOptions& options) {
    ModelOptions m;
    m.trail_steps = options.trail_steps;
    return m;
  }

  double Now() const { return std::chrono::duration<double>(dds::Clock::now() - start_).count(); }

  void Dispatch(const dds::Event& event, double now) {
    if (const auto* truth = std::get_if<dds::Received<protocol::TruthMsg>>(&event)) {
      model_.OnTruth(truth->msg, now);
    } else if (const auto* range = std::get_if<dds::Received<protocol::RangeMsg>>(&event)) {
      model_.OnRange(range->msg, range->from, now);
    } else if (const auto* state = std::get_if<dds::Received<protocol::StateMsg>>(&event)) {
      if (node_.Secure() && node_.AuthorizedAgent(state->from) != state->msg.agent_id) {
        model_.OnUnauthorised(state->msg.agent_id, now);
        return;
      }
      model_.OnState(state->msg, state->from, state->written_unix_s, now);
    } else if (const auto* change = std::get_if<dds::LivelinessChange>(&event)) {
      const WriterKind kind = change->topic == dds::Topic::kAgentState ? WriterKind::kState
                              : change->topic == dds::Topic::kRange    ? WriterKind::kRange
                                                                       : WriterKind::kOther;
      model_.OnLiveliness(kind, change->writer, change->alive, now);
    }
  }

  void OpenFiles() {
    if (context_.options.out_dir.empty()) return;
    const std::filesystem::path dir(context_.options.out_dir);
    series_csv_.emplace((dir / "observer.csv").string(),
                        "step,t,agent,error,max_error,sigma,pcrlb,optimality_ratio,alive");
    marks_csv_.emplace((dir / "observer_marks.csv").string(), "id,step,t_observer,kind,agent,text");
    latency_csv_.emplace((dir / "observer_latency.csv").string(), "agent,step,write_to_send_s");
  }

  // The states new in this update: from their write to now (the update is on its way).
  void NoteLatencies(const nlohmann::json& update, double sent_unix_s) {
    for (const nlohmann::json& a : update["agents"]) {
      if (!a.contains("step") || !a.contains("written")) continue;
      const AgentId id = a["id"].get<AgentId>();
      const StepIndex step = a["step"].get<StepIndex>();
      StepIndex& last = latency_step_[id];
      if (step <= last) continue;
      last = step;
      if (latency_csv_) {
        latency_csv_->WriteLine(std::to_string(id) + "," + std::to_string(step) + "," +
                                FormatDouble(sent_unix_s - a["written"].get<double>()));
      }
    }
  }

  // New series points and marks into the files, and new marks into the log.
  void WriteFiles() {
    // Only the tail is new: find where it starts from the back (the series holds thousands).
    const auto& series = model_.series();
    auto first_new = series.end();
    while (first_new != series.begin() && std::prev(first_new)->step > written_step_) --first_new;
    for (auto it = first_new; it != series.end(); ++it) {
      const SeriesPoint& p = *it;
      written_step_ = p.step;
      if (series_csv_) {
        series_csv_->WriteLine(std::to_string(p.step) + "," + Cell(p.t_s) + "," + std::to_string(p.agent) +
                               "," + Cell(p.error_m) + "," + Cell(p.max_error_m) + "," + Cell(p.sigma_m) +
                               "," + Cell(p.pcrlb_m) + "," + Cell(p.ratio) + "," + std::to_string(p.alive));
      }
    }
    const auto& marks = model_.marks();
    auto first_mark = marks.end();
    while (first_mark != marks.begin() && std::prev(first_mark)->id > written_mark_) --first_mark;
    for (auto it = first_mark; it != marks.end(); ++it) {
      const Mark& m = *it;
      written_mark_ = m.id;
      context_.log->info("mark at step {}: {}", m.step, m.text);
      if (marks_csv_) {
        marks_csv_->WriteLine(std::to_string(m.id) + "," + std::to_string(m.step) + "," + FormatDouble(m.t_s) +
                              "," + m.kind + "," + std::to_string(m.agent) + "," + Quoted(m.text));
      }
    }
  }

  dds::ProcessContext& context_;
  ObserverOptions options_;
  const dds::Clock::time_point start_ = dds::Clock::now();
  std::mutex mutex_;  // the model, between the DDS loop and the HTTP threads
  dds::Node node_;
  LiveModel model_;
  LiveServer server_;
  std::atomic<bool> stop_{false};
  std::optional<CsvWriter> series_csv_;
  std::optional<CsvWriter> marks_csv_;
  std::optional<CsvWriter> latency_csv_;
  std::map<AgentId, StepIndex> latency_step_;
  StepIndex written_step_ = 0;
  std::int64_t written_mark_ = 0;
};

}  // namespace
}  // namespace deif::observer

int main(int argc, char** argv) {
  deif::observer::ObserverOptions options;
  deif::dds::ProcessSpec spec;
  spec.program = "deif_observer";
  spec.description =
      "deif_observer: a passive participant of a run that serves a live page over HTTP "
      "(server-sent events); it never publishes on the network's topics";
  spec.add_options = [&options](CLI::App& cli) {
    cli.add_option("--port", options.port, "HTTP port (0: any free port; the URL is printed)")
        ->check(CLI::Range(0, 65535));
    cli.add_option("--bind", options.bind, "address to listen on (default 0.0.0.0: every interface)");
    cli.add_option("--url-host", options.url_host,
                   "host name or address to print in the URL (default: the bind address, or "
                   "the first non-loopback IPv4 address)");
    cli.add_option("--trail", options.trail_steps, "steps of trail kept per agent")
        ->check(CLI::Range(1, 100000));
    cli.add_option("--observer-id", options.observer_id,
                   "M of the participant's name observer-M (its certificate with DDS Security)")
        ->check(CLI::Range(1, 64));
    cli.add_option("--nice", options.nice, "lower this process's CPU priority (0..19)")
        ->check(CLI::Range(0, 19));
  };
  spec.logger_name = [] { return std::string("observer"); };
  spec.identity_name = [&options] { return "observer-" + std::to_string(options.observer_id); };
  spec.make = [&options](deif::dds::ProcessContext& context) {
    return std::make_unique<deif::observer::Observer>(context, options);
  };
  return deif::dds::RunMain(argc, argv, spec);
}
