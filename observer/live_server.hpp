// The observer's HTTP side (docs/LIVE.md), on cpp-httplib:
//   GET /          the page (observer/page/index.html, embedded in the binary)
//   GET /events    server-sent events: one "snapshot", then an "update" per Publish()
//   GET /snapshot  the snapshot as JSON (for scripts)
//   GET /healthz   "ok"
// Updates are pre-serialised once and shared by every client; a client that falls more
// than a queue behind gets a fresh snapshot instead of the updates it missed.
#pragma once

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <utility>

namespace httplib {
class Server;
}

namespace deif::observer {

class LiveServer {
 public:
  // A snapshot (JSON text) and the sequence number of the last update it includes. It
  // must be consistent with Publish(): build it under the lock Publish() is called under.
  using SnapshotSource = std::function<std::pair<std::string, std::uint64_t>()>;

  LiveServer(std::string page_html, SnapshotSource snapshot);
  ~LiveServer();  // Stop()
  LiveServer(const LiveServer&) = delete;
  LiveServer& operator=(const LiveServer&) = delete;

  // Binds address:port (port 0: any free port) and serves on its own threads. Returns the
  // port. Throws std::runtime_error if it cannot bind.
  int Start(const std::string& address, int port);
  // Sends an update (JSON text) to every connected client; returns its sequence number.
  std::uint64_t Publish(std::string json);
  std::uint64_t LastSeq() const;
  int Clients() const;
  void Stop();

 private:
  struct Message {
    std::uint64_t seq;
    std::shared_ptr<const std::string> frame;  // "event: update\ndata: ...\n\n"
  };
  bool StreamTo(std::uint64_t& next_seq, bool& fresh, const std::function<bool(const std::string&)>& write);

  std::string page_;
  SnapshotSource snapshot_;
  std::unique_ptr<httplib::Server> server_;
  std::thread thread_;

  mutable std::mutex mutex_;
  std::condition_variable cv_;
  std::deque<Message> queue_;  // the latest updates
  std::uint64_t last_seq_ = 0;
  bool stopping_ = false;
  int clients_ = 0;
};

// "event: <name>\ndata: <json>\n\n" (the JSON is one line).
std::string SseFrame(const std::string& event, const std::string& json);

}  // namespace deif::observer
