#include "dds/shm_ports.hpp"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <system_error>
#include <utility>

namespace deif::dds {
namespace {

constexpr const char* kPortPrefix = "fastrtps_port";
constexpr const char* kDeleted = " (deleted)";

bool EndsWith(const std::string& s, const std::string& tail) {
  return s.size() >= tail.size() && s.compare(s.size() - tail.size(), tail.size(), tail) == 0;
}

std::string ReadAll(const char* path) {
  std::ifstream in(path);
  std::ostringstream text;
  text << in.rdbuf();
  return text.str();
}

std::string PortPath(const std::string& dir, int port) {
  return dir + "/" + kPortPrefix + std::to_string(port);
}

}  // namespace

std::optional<int> ListenedPort(const std::string& fd_target, const std::string& dir) {
  std::string target = fd_target;
  if (EndsWith(target, kDeleted)) target.resize(target.size() - std::string(kDeleted).size());
  const std::string prefix = dir + "/" + kPortPrefix;
  if (target.compare(0, prefix.size(), prefix) != 0) return std::nullopt;
  if (!EndsWith(target, "_el")) return std::nullopt;
  const std::string digits = target.substr(prefix.size(), target.size() - prefix.size() - 3);
  if (digits.empty() || digits.size() > 6 || digits.find_first_not_of("0123456789") != std::string::npos) {
    return std::nullopt;
  }
  return std::stoi(digits);
}

std::set<unsigned long> MappedInodes(const std::string& maps, const std::string& path) {
  // Each line: address perms offset dev inode [path], the path after padding.
  std::set<unsigned long> inodes;
  std::istringstream lines(maps);
  std::string line;
  while (std::getline(lines, line)) {
    std::istringstream fields(line);
    std::string address, perms, offset, device;
    unsigned long inode = 0;
    if (!(fields >> address >> perms >> offset >> device >> inode)) continue;
    std::string name;
    std::getline(fields, name);
    name.erase(0, name.find_first_not_of(' '));
    if (EndsWith(name, kDeleted)) name.resize(name.size() - std::string(kDeleted).size());
    if (name == path) inodes.insert(inode);
  }
  return inodes;
}

ShmPortWatch::ShmPortWatch(std::vector<int> ports, double hold_s, std::string dir)
    : ports_(std::move(ports)), hold_s_(hold_s), dir_(std::move(dir)) {}

std::vector<int> ShmPortWatch::ListenedPorts(const std::string& dir) {
  std::set<int> ports;
  std::error_code ec;
  for (const auto& entry : std::filesystem::directory_iterator("/proc/self/fd", ec)) {
    std::error_code link_ec;
    const auto target = std::filesystem::read_symlink(entry.path(), link_ec);
    if (link_ec) continue;  // closed meanwhile
    if (const auto port = ListenedPort(target.string(), dir)) ports.insert(*port);
  }
  return {ports.begin(), ports.end()};
}

std::vector<int> ShmPortWatch::Replaced() {
  std::vector<int> replaced;
  std::optional<std::string> maps;  // read only when a port's file is not the one seen mapped last
  for (int port : ports_) {
    const std::string path = PortPath(dir_, port);
    struct stat st {};
    if (::stat(path.c_str(), &st) != 0) {
      replaced.push_back(port);
      mapped_.erase(port);
      continue;
    }
    const auto seen = mapped_.find(port);
    if (seen != mapped_.end() && seen->second == st.st_ino) continue;  // the same file: still mapped
    if (!maps) maps = ReadAll("/proc/self/maps");
    if (MappedInodes(*maps, path).count(st.st_ino) == 0) {
      replaced.push_back(port);
      mapped_.erase(port);
    } else {
      mapped_[port] = st.st_ino;
    }
  }
  return replaced;
}

std::vector<int> ShmPortWatch::Lost(double now_s) {
  std::vector<int> replaced = Replaced();
  if (replaced.empty()) {
    replaced_since_.reset();
    return {};
  }
  if (!replaced_since_) replaced_since_ = now_s;
  if (now_s - *replaced_since_ < hold_s_) return {};
  return replaced;
}

PortListener ListenerOf(int port, const std::string& dir) {
  const std::string path = PortPath(dir, port) + "_el";
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return errno == ENOENT ? PortListener::kAbsent : PortListener::kHeld;  // unreadable: say nothing
  PortListener state = PortListener::kHeld;
  if (::flock(fd, LOCK_SH | LOCK_NB) == 0) {
    ::flock(fd, LOCK_UN);
    state = PortListener::kFree;
  }
  ::close(fd);
  return state;
}

}  // namespace deif::dds
