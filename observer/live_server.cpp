#include "observer/live_server.hpp"

#include <chrono>
#include <stdexcept>

#include <httplib.h>

namespace deif::observer {

namespace {

constexpr std::size_t kQueueLength = 64;   // updates kept for clients that lag (3 s at 20/s)
constexpr auto kKeepAlive = std::chrono::seconds(10);  // an SSE comment when nothing happens
constexpr int kThreads = 24;               // concurrent connections (each page holds one)

}  // namespace

std::string SseFrame(const std::string& event, const std::string& json) {
  return "event: " + event + "\ndata: " + json + "\n\n";
}

LiveServer::LiveServer(std::string page_html, SnapshotSource snapshot)
    : page_(std::move(page_html)), snapshot_(std::move(snapshot)), server_(std::make_unique<httplib::Server>()) {}

LiveServer::~LiveServer() { Stop(); }

int LiveServer::Start(const std::string& address, int port) {
  httplib::Server& s = *server_;
  s.new_task_queue = [] { return new httplib::ThreadPool(kThreads); };
  s.set_keep_alive_timeout(2);
  s.set_write_timeout(5, 0);
  s.set_tcp_nodelay(true);
  s.Get("/", [this](const httplib::Request&, httplib::Response& res) {
    res.set_header("Cache-Control", "no-cache");
    res.set_content(page_, "text/html; charset=utf-8");
  });
  s.Get("/healthz", [](const httplib::Request&, httplib::Response& res) {
    res.set_content("ok\n", "text/plain");
  });
  s.Get("/snapshot", [this](const httplib::Request&, httplib::Response& res) {
    res.set_header("Cache-Control", "no-cache");
    res.set_content(snapshot_().first, "application/json");
  });
  s.Get("/events", [this](const httplib::Request&, httplib::Response& res) {
    res.set_header("Cache-Control", "no-cache");
    res.set_header("X-Accel-Buffering", "no");
    {
      std::lock_guard<std::mutex> lock(mutex_);
      ++clients_;
    }
    auto next_seq = std::make_shared<std::uint64_t>(0);
    auto fresh = std::make_shared<bool>(true);  // a snapshot comes first
    res.set_chunked_content_provider(
        "text/event-stream",
        [this, next_seq, fresh](std::size_t, httplib::DataSink& sink) {
          const bool go_on = StreamTo(*next_seq, *fresh, [&sink](const std::string& frame) {
            return sink.write(frame.data(), frame.size());
          });
          if (!go_on) sink.done();
          return true;
        },
        [this](bool) {
          std::lock_guard<std::mutex> lock(mutex_);
          --clients_;
        });
  });
  const int bound = port == 0 ? s.bind_to_any_port(address) : (s.bind_to_port(address, port) ? port : -1);
  if (bound <= 0) {
    throw std::runtime_error("cannot listen on " + address + ":" + std::to_string(port));
  }
  thread_ = std::thread([this] { server_->listen_after_bind(); });
  return bound;
}

bool LiveServer::StreamTo(std::uint64_t& next_seq, bool& fresh,
                          const std::function<bool(const std::string&)>& write) {
  if (fresh) {
    auto [json, seq] = snapshot_();
    fresh = false;
    next_seq = seq + 1;
    return write(SseFrame("snapshot", json));
  }
  std::vector<std::shared_ptr<const std::string>> frames;
  {
    std::unique_lock<std::mutex> lock(mutex_);
    const bool ready = cv_.wait_for(lock, kKeepAlive, [&] { return stopping_ || last_seq_ >= next_seq; });
    if (stopping_) return false;
    if (!ready) {
      lock.unlock();
      return write(": keep-alive\n\n");
    }
    if (queue_.empty() || queue_.front().seq > next_seq) {
      fresh = true;  // fell behind the queue: start over from a snapshot
    } else {
      for (const Message& m : queue_) {
        if (m.seq >= next_seq) frames.push_back(m.frame);
      }
      next_seq = last_seq_ + 1;
    }
  }
  if (fresh) return StreamTo(next_seq, fresh, write);
  for (const auto& frame : frames) {
    if (!write(*frame)) return false;
  }
  return true;
}

std::uint64_t LiveServer::Publish(std::string json) {
  auto frame = std::make_shared<const std::string>(SseFrame("update", json));
  std::uint64_t seq = 0;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    seq = ++last_seq_;
    queue_.push_back({seq, std::move(frame)});
    while (queue_.size() > kQueueLength) queue_.pop_front();
  }
  cv_.notify_all();
  return seq;
}

std::uint64_t LiveServer::LastSeq() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return last_seq_;
}

int LiveServer::Clients() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return clients_;
}

void LiveServer::Stop() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (stopping_) return;
    stopping_ = true;
  }
  cv_.notify_all();
  if (server_) server_->stop();
  if (thread_.joinable()) thread_.join();
}

}  // namespace deif::observer
