#include "dds/application.hpp"

#include <fcntl.h>
#include <pthread.h>
#include <signal.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <filesystem>
#include <fstream>
#include <memory>
#include <mutex>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include <CLI/CLI.hpp>
#include <spdlog/sinks/basic_file_sink.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include "common/protocol/agent_protocol.hpp"
#include "common/protocol/messages.hpp"
#include "dds/node.hpp"
#include "dds/security.hpp"

namespace deif::dds {

namespace {

// Blocks SIGINT/SIGTERM in every thread (call before any thread exists) and calls the
// handler from a dedicated thread when one arrives.
class SignalStopper {
 public:
  SignalStopper() {
    sigset_t set = Signals();
    pthread_sigmask(SIG_BLOCK, &set, nullptr);  // inherited by every thread created later
    thread_ = std::thread([this] {
      sigset_t wait_set = Signals();
      for (;;) {
        int signal_number = 0;
        if (sigwait(&wait_set, &signal_number) != 0) continue;
        if (exiting_.load()) return;
        std::lock_guard<std::mutex> lock(mutex_);
        if (on_signal_) on_signal_(signal_number);
      }
    });
  }
  ~SignalStopper() {
    exiting_.store(true);
    pthread_kill(thread_.native_handle(), SIGTERM);
    thread_.join();
  }
  SignalStopper(const SignalStopper&) = delete;
  SignalStopper& operator=(const SignalStopper&) = delete;
  void SetHandler(std::function<void(int)> on_signal) {
    std::lock_guard<std::mutex> lock(mutex_);
    on_signal_ = std::move(on_signal);
  }

 private:
  static sigset_t Signals() {
    sigset_t set;
    sigemptyset(&set);
    sigaddset(&set, SIGINT);
    sigaddset(&set, SIGTERM);
    return set;
  }
  std::atomic<bool> exiting_{false};
  std::mutex mutex_;
  std::function<void(int)> on_signal_;
  std::thread thread_;
};

std::shared_ptr<spdlog::logger> MakeLogger(const std::string& name, const std::string& log_dir,
                                           bool append) {
  std::vector<spdlog::sink_ptr> sinks;
  sinks.push_back(std::make_shared<spdlog::sinks::stderr_color_sink_mt>());
  if (!log_dir.empty()) {
    sinks.push_back(
        std::make_shared<spdlog::sinks::basic_file_sink_mt>(log_dir + "/" + name + ".log", !append));
  }
  auto logger = std::make_shared<spdlog::logger>(name, sinks.begin(), sinks.end());
  logger->set_pattern("[%Y-%m-%d %H:%M:%S.%e] [%n] [%l] %v");
  logger->flush_on(spdlog::level::info);
  spdlog::register_logger(logger);
  return logger;
}

// A folder the process writes into: created when missing, and checked writable.
void PrepareFolder(const std::string& dir, const char* option) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  const std::filesystem::path probe = std::filesystem::path(dir) / ".deif_write_test";
  std::ofstream out(probe);
  if (ec || !out) throw ConfigError(option, "", 0, "cannot write to the folder '" + dir + "'");
  out.close();
  std::filesystem::remove(probe, ec);
}

bool AllDigits(const std::string& text) {
  return !text.empty() && text.size() <= 20 && text.find_first_not_of("0123456789") == std::string::npos;
}

Config LoadProcessConfig(const ProcessOptions& options) {
  std::vector<std::string> overrides = options.overrides;
  if (!options.domain.empty()) {
    if (!AllDigits(options.domain) || std::stoull(options.domain) > 232) {
      throw ConfigError("--domain", "network.domain_id", 0,
                        "must be an integer in 0..232 (got '" + options.domain + "')");
    }
    overrides.push_back("network.domain_id=" + options.domain);
  }
  if (!options.seed.empty()) {
    bool ok = AllDigits(options.seed);
    if (ok) {
      errno = 0;
      std::strtoull(options.seed.c_str(), nullptr, 10);
      ok = errno != ERANGE;
    }
    if (!ok) {
      throw ConfigError("--seed", "scenario.seed", 0,
                        "expected a non-negative integer below 2^64 (got '" + options.seed + "')");
    }
    overrides.push_back("scenario.seed=" + options.seed);
  }
  return LoadConfig(options.config_path, overrides);
}

// How a process ends once its participant is to be deleted, if the deletion hangs or
// crashes: with the code Run() returned, or by starting again in place with these
// arguments. Plain data: a signal handler reads it.
struct Ending {
  int code = 0;
  char* const* exec_argv = nullptr;  // not null: start again in place
};
Ending g_ending;

// Async-signal-safe: the crash guard calls it from a signal handler.
[[noreturn]] void EndNow() {
  if (g_ending.exec_argv != nullptr) {
    sigset_t none;
    sigemptyset(&none);
    sigprocmask(SIG_SETMASK, &none, nullptr);  // the new image must not inherit a blocked SIGABRT
    ::execv("/proc/self/exe", g_ending.exec_argv);
  }
  std::_Exit(g_ending.code);
}

extern "C" void OnTeardownCrash(int /*signal_number*/) {
  static const char kText[] =
      "Fast DDS crashed while deleting the participant; ending without it (docs/FASTDDS_NOTES.md, "
      "\"Leaving while the run goes on\")\n";
  [[maybe_unused]] const ssize_t written = ::write(STDERR_FILENO, kText, sizeof kText - 1);
  EndNow();
}

// Deleting a participant can hang for good in Fast DDS 2.9.1 when a secure peer leaves at the
// same moment (docs/FASTDDS_NOTES.md, "Security"), and can abort in PDP.cpp:1140 when peers
// leave at the same moment (docs/FASTDDS_NOTES.md, "Leaving at the end of a run"). By then the
// process has written its rows, counters and log, so the deletion gets kTeardownBoundS and a
// crash inside it ends the process as planned: with the code it would have returned (or
// starting again in place), and its peers see it leave when its lease runs out.
constexpr double kTeardownBoundS = 10.0;

void GuardTeardown(std::shared_ptr<spdlog::logger> log) {
  struct sigaction action {};
  action.sa_handler = OnTeardownCrash;
  sigemptyset(&action.sa_mask);
  action.sa_flags = SA_RESETHAND;  // a second crash inside the handler ends the process
  for (int signal_number : {SIGABRT, SIGSEGV, SIGBUS}) sigaction(signal_number, &action, nullptr);
  std::thread([log] {
    std::this_thread::sleep_for(std::chrono::duration<double>(kTeardownBoundS));
    log->warn("the DDS participant was not deleted within {} s (a known Fast DDS 2.9.1 deadlock, "
              "docs/FASTDDS_NOTES.md); {} without it",
              kTeardownBoundS, g_ending.exec_argv != nullptr ? "starting again" : "exiting");
    log->flush();
    std::fflush(stdout);
    std::fflush(stderr);
    EndNow();
  }).detach();
}

// Marks every descriptor but stdin, stdout and stderr close-on-exec: Fast DDS's lock files
// among them, so that its peers find the old ports and segments dead.
void CloseOnExec() {
  std::error_code ec;
  std::vector<int> fds;
  for (const auto& entry : std::filesystem::directory_iterator("/proc/self/fd", ec)) {
    const std::string name = entry.path().filename().string();
    if (AllDigits(name)) fds.push_back(std::atoi(name.c_str()));
  }
  for (int fd : fds) {
    if (fd > 2) ::fcntl(fd, F_SETFD, FD_CLOEXEC);
  }
}

// This program's command again, each option of `replaced` with its new value instead of the
// old one, and --append (docs/RUNNING.md, "Restarting in place").
std::vector<std::string> RestartArguments(int argc, char** argv, const RestartOptions& replaced) {
  std::vector<std::string> args;
  for (int i = 0; i < argc; ++i) {
    const std::string a = argv[i];
    const auto is = [&a](const auto& option) { return a == option.first; };
    const auto is_with_value = [&a](const auto& option) { return a.rfind(option.first + "=", 0) == 0; };
    if (std::any_of(replaced.begin(), replaced.end(), is)) {
      ++i;  // and its value
      continue;
    }
    if (std::any_of(replaced.begin(), replaced.end(), is_with_value)) continue;
    args.push_back(a);
  }
  for (const auto& [option, value] : replaced) {
    args.push_back(option);
    args.push_back(value);
  }
  if (std::find(args.begin(), args.end(), "--append") == args.end()) args.emplace_back("--append");
  return args;
}

// RestartArguments and the environment of a restart in place, made before the participant
// is deleted, so that a hang or crash in the deletion can still exec it.
class RestartCommand {
 public:
  RestartCommand(int argc, char** argv, const RestartOptions& replaced)
      : args_(RestartArguments(argc, argv, replaced)) {
    for (std::string& a : args_) argv_.push_back(a.data());
    argv_.push_back(nullptr);
    ::setenv(kRestartsVariable, std::to_string(RestartsInPlace() + 1).c_str(), 1);
    ::setenv(kShmPortsUsedVariable, ShmPortsUsedSoFar().c_str(), 1);
    CloseOnExec();
  }
  RestartCommand(const RestartCommand&) = delete;
  RestartCommand& operator=(const RestartCommand&) = delete;

  char* const* argv() const { return argv_.data(); }

  // Returns why it could not.
  std::string Exec() const {
    CloseOnExec();  // and what was opened since
    ::execv("/proc/self/exe", argv_.data());
    return std::string("cannot start again in place: ") + std::strerror(errno);
  }

 private:
  std::vector<std::string> args_;
  std::vector<char*> argv_;
};

// This process's command line, for OnTerminate (PrepareTerminate): main's argv lives as long
// as the process.
int g_argc = 0;
char** g_argv = nullptr;
const char* g_program = "";

// A Fast DDS 2.9.1 shared-memory receive thread locks its port's interprocess mutex once more
// after each message, outside any try (SharedMemChannelResource::perform_listen_operation,
// stop_processing_buffer): when another process holds that mutex longer than Fast DDS's lock
// timeout (stopped, starved, or killed while it pushed), the exception ends the thread and
// std::terminate would abort a process that is not broken (docs/FASTDDS_NOTES.md, "An
// exception that ends a thread"). Such a process starts again in place (RestartCommand, as
// any restart in place, at most kMaxRestartsInPlace times); any other uncaught exception is
// logged and aborts, which while the run goes on is a crash like any other (ArmCrashRestart).
[[noreturn]] void OnTerminate() {
  std::string what = "not a std::exception";
  try {
    if (const std::exception_ptr e = std::current_exception()) std::rethrow_exception(e);
    what = "no exception";
  } catch (const std::exception& e) {
    what = e.what();
  } catch (...) {
  }
  const bool lock_timeout = what.rfind(kLockTimeout, 0) == 0;
  const bool may = lock_timeout && g_argv != nullptr && RestartsInPlace() < kMaxRestartsInPlace;
  std::fprintf(stderr, "%s: error: an exception ended a thread (%s); %s (docs/FASTDDS_NOTES.md, \"An exception that ends a thread\")\n",
               g_program, what.c_str(),
               may ? "it starts again in place" : lock_timeout ? "it already started again in place too often; aborting" : "aborting");
  std::fflush(stderr);
  if (may) {
    const std::string why = RestartCommand(g_argc, g_argv, {}).Exec();  // only on failure
    std::fprintf(stderr, "%s: error: %s\n", g_program, why.c_str());
  }
  std::abort();
}

void PrepareTerminate(int argc, char** argv, const char* program) {
  g_argc = argc;
  g_argv = argv;
  g_program = program;
  std::set_terminate(OnTerminate);
}

// A crash while the run goes on (docs/RUNNING.md, "A crash"): Fast DDS 2.9.1 can crash a
// process of a starved host in its discovery (an assertion in PDP.cpp, a SIGSEGV in its
// endpoint discovery), and a sensor must not be lost for that. While the application runs,
// SIGSEGV, SIGBUS, SIGFPE, SIGILL and SIGABRT start the process again in place, as any
// restart in place (at most kMaxRestartsInPlace times), with everything the signal handler
// needs made beforehand: it only writes, marks descriptors close-on-exec and execs. What
// it cannot do is delete its participant first, so its peers see the process end (its
// ports' locks released) and it rejoins as a restarted agent; the step in flight is lost.
// Made with the command of the moment it was armed (the target's --start-step then).
struct CrashRestart {
  std::vector<std::string> args;
  std::vector<char*> argv;
  std::vector<std::string> env;
  std::vector<char*> envp;
  std::string program;
  std::string message;  // "<program>: error: crashed (signal "
  std::string may_text;
  std::string may_not_text;
  bool may = false;
  int max_fd = 1024;
};
CrashRestart* g_crash = nullptr;  // set once, never freed: a handler may read it at any time

constexpr int kCrashSignals[] = {SIGSEGV, SIGBUS, SIGFPE, SIGILL, SIGABRT};

void WriteAll(const char* text, std::size_t size) {
  while (size > 0) {
    const ssize_t n = ::write(STDERR_FILENO, text, size);
    if (n <= 0) return;
    text += n;
    size -= static_cast<std::size_t>(n);
  }
}

// Starts the process again in place with g_crash's command, if it may (returns if the exec
// failed or it may not).
void ExecCrashRestart(const CrashRestart& c) {
  if (!c.may) return;
  for (int fd = 3; fd < c.max_fd; ++fd) ::fcntl(fd, F_SETFD, FD_CLOEXEC);
  sigset_t none;
  sigemptyset(&none);
  sigprocmask(SIG_SETMASK, &none, nullptr);  // the new image must not inherit a blocked signal
  ::execve("/proc/self/exe", c.argv.data(), c.envp.data());
}

extern "C" void OnCrash(int signal_number) {
  const CrashRestart& c = *g_crash;
  WriteAll(c.message.data(), c.message.size());
  char digits[4];
  int n = 0;
  for (int v = signal_number; n < 3 && (n == 0 || v > 0); v /= 10) digits[n++] = static_cast<char>('0' + v % 10);
  for (int i = n - 1; i >= 0; --i) WriteAll(&digits[i], 1);
  const std::string& rest = c.may ? c.may_text : c.may_not_text;
  WriteAll(rest.data(), rest.size());
  ExecCrashRestart(c);
  ::signal(signal_number, SIG_DFL);  // SA_RESETHAND did so already; and if the exec failed
  ::raise(signal_number);
}

// Whether a crash now starts the process again (ArmCrashRestart, DisarmCrashRestart).
std::atomic<bool> g_crash_armed{false};

// A reader caught in Fast DDS 2.9.1's loop over a lost change (SetReaderLoopHandler): the
// thread in it never comes back, and the process, whose writers stay alive, holds up every
// lock-step step of its peers. While the run goes on it starts again in place, as after a
// crash; else it ends.
void OnReaderLoop() {
  const CrashRestart* c = g_crash_armed.load() ? g_crash : nullptr;
  const std::string& program = c != nullptr ? c->program : std::string("deif");
  const bool may = c != nullptr && c->may;
  const std::string text =
      program + ": error: a reader is caught in Fast DDS's loop over a change its history lost track of " +
      "(docs/FASTDDS_NOTES.md, \"A reader that hands out one sample for ever\"); " +
      (may ? "it starts again in place\n" : "ending\n");
  WriteAll(text.data(), text.size());
  if (c != nullptr) ExecCrashRestart(*c);
  std::_Exit(protocol::kExitRuntimeError);
}

void ArmCrashRestart(int argc, char** argv, const RestartOptions& replaced, const char* program) {
  auto* c = new CrashRestart;
  c->args = RestartArguments(argc, argv, replaced);
  for (std::string& a : c->args) c->argv.push_back(a.data());
  c->argv.push_back(nullptr);
  const std::string restarts = std::string(kRestartsVariable) + "=";
  const std::string ports = std::string(kShmPortsUsedVariable) + "=";
  for (char** e = environ; *e != nullptr; ++e) {
    const std::string entry = *e;
    if (entry.rfind(restarts, 0) != 0 && entry.rfind(ports, 0) != 0) c->env.push_back(entry);
  }
  c->env.push_back(restarts + std::to_string(RestartsInPlace() + 1));
  c->env.push_back(ports + ShmPortsUsedSoFar());
  for (std::string& e : c->env) c->envp.push_back(e.data());
  c->envp.push_back(nullptr);
  c->may = RestartsInPlace() < kMaxRestartsInPlace;
  c->program = program;
  c->message = std::string(program) + ": error: crashed (signal ";
  c->may_text = ") while the run goes on; it starts again in place (docs/RUNNING.md, \"A crash\")\n";
  c->may_not_text = ") while the run goes on, after " + std::to_string(RestartsInPlace()) +
                    " restart(s) in place; ending (docs/RUNNING.md, \"A crash\")\n";
  const long open_max = ::sysconf(_SC_OPEN_MAX);
  c->max_fd = open_max > 0 && open_max < 65536 ? static_cast<int>(open_max) : 65536;
  g_crash = c;
  struct sigaction action {};
  action.sa_handler = OnCrash;
  sigemptyset(&action.sa_mask);
  action.sa_flags = SA_RESETHAND;  // a crash inside the handler ends the process
  for (int signal_number : kCrashSignals) sigaction(signal_number, &action, nullptr);
  g_crash_armed.store(true);
  SetReaderLoopHandler(OnReaderLoop);
}

// The run is over (or the process leaves on its own): a crash from now on is not restarted.
void DisarmCrashRestart() {
  g_crash_armed.store(false);
  for (int signal_number : kCrashSignals) ::signal(signal_number, SIG_DFL);
}

}  // namespace

void LogAt(spdlog::logger& log, protocol::LogLevel level, const std::string& text) {
  switch (level) {
    case protocol::LogLevel::kDebug: log.debug("{}", text); break;
    case protocol::LogLevel::kInfo: log.info("{}", text); break;
    case protocol::LogLevel::kWarn: log.warn("{}", text); break;
    case protocol::LogLevel::kError: log.error("{}", text); break;
  }
}

void Carry(const protocol::Log& action, spdlog::logger& log) { LogAt(log, action.level, action.text); }

void Carry(const protocol::Finish& action, spdlog::logger& log, std::optional<int>& exit_code) {
  exit_code = action.exit_code;
  LogAt(log, action.exit_code == 0 ? protocol::LogLevel::kInfo : protocol::LogLevel::kError,
        action.reason);
}

std::chrono::steady_clock::time_point WakeBy(std::optional<double> deadline_s, double max_wait_s) {
  auto wake = Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(max_wait_s));
  if (deadline_s) {
    const auto deadline = Clock::time_point(std::chrono::duration_cast<Clock::duration>(
        std::chrono::duration<double>(*deadline_s)));
    wake = std::min(wake, deadline);
  }
  return wake;
}

void CheckRunName(const std::string& name) {
  const bool ok = !name.empty() && name.size() <= 64 &&
                  name.find_first_not_of("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz"
                                         "0123456789._-") == std::string::npos;
  if (!ok) {
    throw ConfigError("--run", "", 0,
                      "a run name is 1..64 characters of letters, digits, '.', '_' and '-' (got '" +
                          name + "')");
  }
}

std::string DefaultRunName(const Config& config) {
  char buffer[32];
  std::snprintf(buffer, sizeof buffer, "cfg-%016llx",
                static_cast<unsigned long long>(protocol::RunTokenOf(ToYaml(config))));
  return buffer;
}

namespace {

// STEP of the first STEP:WHO item of `variable` whose WHO is `who`; 0 when none, and in a
// process that already started again in place.
StepIndex FaultStep(const char* variable, const std::string& who) {
  const char* value = std::getenv(variable);
  if (value == nullptr || RestartsInPlace() > 0) return 0;
  std::stringstream list(value);
  std::string item;
  while (std::getline(list, item, ',')) {
    const std::size_t colon = item.find(':');
    if (colon == std::string::npos || item.substr(colon + 1) != who) continue;
    const std::string step = item.substr(0, colon);
    if (!step.empty() && step.size() < 10 && AllDigits(step)) return std::stoll(step);
  }
  return 0;
}

}  // namespace

StepIndex FaultDeafStep(const std::string& who) { return FaultStep("DEIF_FAULT_DEAF", who); }

StepIndex FaultThrowStep(const std::string& who) { return FaultStep("DEIF_FAULT_THROW", who); }

StepIndex FaultCrashStep(const std::string& who) { return FaultStep("DEIF_FAULT_CRASH", who); }

StepIndex FaultReaderLoopStep(const std::string& who) { return FaultStep("DEIF_FAULT_READER_LOOP", who); }

void CrashInAThreadForTest(bool wait) {
  std::thread crash([] { ::raise(SIGSEGV); });
  if (wait) {
    crash.join();  // never returns: the process starts again in place, or ends
  } else {
    crash.detach();
  }
}

void ThrowInAThreadForTest() {
  std::thread([] { throw std::runtime_error(std::string(kLockTimeout) + " (DEIF_FAULT_THROW)"); }).detach();
}

bool MayRestartInPlace(spdlog::logger& log, const std::string& why, const std::string& when) {
  const int restarts = RestartsInPlace();
  if (restarts >= kMaxRestartsInPlace) {
    log.error("{}, after {} restart(s) in place; giving up {}", why, restarts, when);
    return false;
  }
  log.error("{}; {} it starts again in place", why, when);
  return true;
}

bool RestartForLostPorts(Node& node, spdlog::logger& log, const std::string& when, bool& watching) {
  if (!watching) return false;
  const std::vector<int> lost = node.PortsLost();
  if (lost.empty()) return false;
  std::string ports;
  for (int port : lost) ports += (ports.empty() ? "" : ", ") + std::to_string(port);
  const std::string why =
      std::string("a peer replaced this process's shared-memory port") + (lost.size() > 1 ? "s " : " ") + ports +
      " (Fast DDS took it for a dead process's): whoever opened it since writes where this process does not read "
      "(docs/FASTDDS_NOTES.md, \"A port replaced under its listener\")";
  if (MayRestartInPlace(log, why, when)) return true;
  watching = false;  // said once; it goes on as it is
  return false;
}

void LogReadersMadeAnew(Node& node, spdlog::logger& log) {
  for (const Topic topic : node.ReadersMadeAnew()) {
    log.warn("the reader of {} handed out the same sample twice (Fast DDS 2.9.1 lost track of it in the reader's "
             "history and would hand it out for ever): made anew (docs/FASTDDS_NOTES.md, \"A reader that hands "
             "out one sample for ever\")",
             NamesOf(topic).name);
  }
}

int RestartsInPlace() {
  const char* value = std::getenv(kRestartsVariable);
  return value != nullptr && AllDigits(value) && std::strlen(value) < 4 ? std::atoi(value) : 0;
}

int RunMain(int argc, char** argv, const ProcessSpec& spec) {
  SignalStopper signals;  // first: blocks SIGINT/SIGTERM before any thread exists
  const auto fail = [&spec](int code, const std::string& what) {
    std::fprintf(stderr, "%s: error: %s\n", spec.program, what.c_str());
    return code;
  };

  CLI::App cli{spec.description};
  ProcessContext context;
  ProcessOptions& options = context.options;
  cli.add_option("--config", options.config_path, "Scenario YAML file (see configs/default.yaml)")
      ->required();
  cli.add_option("--set", options.overrides,
                 "Override a config key: dotted.key=YAML value (repeatable)");
  cli.add_option("--log-dir", options.log_dir, "Also write the log to DIR/<name>.log (created)");
  cli.add_option("--domain", options.domain, "DDS domain id 0..232 (overrides network.domain_id)");
  cli.add_option("--out", options.out_dir, "Run folder for this process's CSV files (created)");
  cli.add_option("--seed", options.seed, "Overrides scenario.seed");
  cli.add_option("--run", options.run_name,
                 "The run's name: processes of other runs on the domain are ignored (default: "
                 "derived from the config)");
  cli.add_flag("--append", options.append, "Append to existing CSV files (a restarted process)");
  if (spec.add_options) spec.add_options(cli);
  try {
    cli.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return cli.exit(e);
  } catch (const CLI::CallForAllHelp& e) {
    return cli.exit(e);
  } catch (const CLI::ParseError& e) {
    return fail(protocol::kExitBadConfig, e.what());
  }

  try {
    context.config = LoadProcessConfig(options);
    if (!options.run_name.empty()) CheckRunName(options.run_name);
    if (spec.check) spec.check(context.config);
    if (!options.out_dir.empty()) PrepareFolder(options.out_dir, "--out");
    if (!options.log_dir.empty()) PrepareFolder(options.log_dir, "--log-dir");
  } catch (const std::exception& e) {  // ConfigError names file, key and line
    return fail(protocol::kExitBadConfig, e.what());
  }
  if (context.config.network.security.enabled) {
    // This process's certificate, key and permissions (docs/SECURITY.md), before anything
    // starts: Fast DDS would only fail to create the participant, or never match a peer.
    try {
      const std::string identity = spec.identity_name ? spec.identity_name() : spec.logger_name();
      CheckSecurityFiles(FilesOf(context.config.network.security.dir, identity));
    } catch (const SecurityError& e) {
      return fail(protocol::kExitBadConfig, std::string("security: ") + e.what());
    }
  }
  context.run_name = options.run_name.empty() ? DefaultRunName(context.config) : options.run_name;

  context.log = MakeLogger(spec.logger_name(), options.log_dir, options.append);
  PrepareTerminate(argc, argv, spec.program);
  try {
    std::unique_ptr<Application> app = spec.make(context);
    Application* raw = app.get();
    auto log = context.log;
    signals.SetHandler([raw, log](int signal_number) {
      log->info("signal {}: stopping", signal_number);
      raw->Stop();
    });
    ArmCrashRestart(argc, argv, app->RestartOptionsOf(), spec.program);
    struct Disarm {
      ~Disarm() { DisarmCrashRestart(); }  // also when Run throws: before the app is deleted
    } disarm;
    const int code = app->Run();
    DisarmCrashRestart();
    signals.SetHandler(nullptr);
    const auto flush = [&log] {
      log->flush();
      std::fflush(stdout);  // not fflush(nullptr): it would wait for stdin, read by another thread
      std::fflush(stderr);
    };
    if (!app->RestartInPlace() && app->LeaveQuietly()) {
      // The run is over for everyone: no goodbye (docs/FASTDDS_NOTES.md, "Leaving at the end
      // of a run").
      app.reset();  // its files are closed; its participant is left to the process's end
      flush();
      spdlog::shutdown();
      std::_Exit(code);
    }
    // The run goes on without this process (stopped, refused, or starting again in place):
    // it deletes its participant, so that no thread of Fast DDS dies holding the lock of a
    // peer's shared-memory port (docs/FASTDDS_NOTES.md, "Leaving while the run goes on").
    std::optional<RestartCommand> restart;
    if (app->RestartInPlace()) restart.emplace(argc, argv, app->RestartOptionsOf());
    g_ending = Ending{code, restart ? restart->argv() : nullptr};
    GuardTeardown(log);
    app.reset();  // deletes the participant: its peers hear at once that it left
    if (restart) {
      flush();
      spdlog::shutdown();
      const std::string why = restart->Exec();  // only on failure
      std::fprintf(stderr, "%s: error: %s\n", spec.program, why.c_str());
    }
    return code;
  } catch (const ConfigError& e) {
    return fail(protocol::kExitBadConfig, e.what());
  } catch (const SecurityError& e) {
    return fail(protocol::kExitBadConfig, std::string("security: ") + e.what());
  } catch (const std::exception& e) {
    context.log->critical("{}", e.what());
    return fail(protocol::kExitRuntimeError, e.what());
  }
}

}  // namespace deif::dds
