// The watch of a process's own shared-memory ports (dds/shm_ports.hpp; docs/FASTDDS_NOTES.md,
// "A port replaced under its listener"): real files mapped and replaced in a directory of the
// test's, as a peer's Fast DDS replaces a port's segment under its listener.
#include <catch2/catch.hpp>

#include <fcntl.h>
#include <sys/file.h>
#include <sys/mman.h>
#include <unistd.h>

#include <filesystem>
#include <random>
#include <string>
#include <vector>

#include "dds/shm_ports.hpp"

namespace fs = std::filesystem;
using deif::dds::ListenedPort;
using deif::dds::MappedInodes;
using deif::dds::ShmPortWatch;

namespace {

// A directory of its own, removed at the end.
struct TempDir {
  fs::path path;
  TempDir() {
    std::random_device rd;
    path = fs::temp_directory_path() / ("deif-shm-ports-" + std::to_string(rd()));
    fs::create_directories(path);
  }
  ~TempDir() {
    std::error_code ec;
    fs::remove_all(path, ec);
  }
};

// A file of one page (created if missing), mapped until the end of the scope.
struct Mapped {
  void* address = MAP_FAILED;
  explicit Mapped(const fs::path& file) {
    const int fd = ::open(file.c_str(), O_RDWR | O_CREAT, 0600);
    REQUIRE(fd >= 0);
    REQUIRE(::ftruncate(fd, 4096) == 0);
    address = ::mmap(nullptr, 4096, PROT_READ | PROT_WRITE, MAP_SHARED, fd, 0);
    ::close(fd);
    REQUIRE(address != MAP_FAILED);
  }
  ~Mapped() { ::munmap(address, 4096); }
};

// A file of one page that this process does not map (a peer's new segment).
void CreateUnmapped(const fs::path& file) {
  const int fd = ::open(file.c_str(), O_RDWR | O_CREAT | O_EXCL, 0600);
  REQUIRE(fd >= 0);
  REQUIRE(::ftruncate(fd, 4096) == 0);
  ::close(fd);
}

}  // namespace

TEST_CASE("a lock file held names the port listened on", "[dds][shm]") {
  CHECK(ListenedPort("/dev/shm/fastrtps_port42160_el", "/dev/shm") == 42160);
  CHECK_FALSE(ListenedPort("/dev/shm/fastrtps_port7400_sl", "/dev/shm"));  // the shared multicast port
  CHECK(ListenedPort("/dev/shm/fastrtps_port42161_el (deleted)", "/dev/shm") == 42161);
  CHECK_FALSE(ListenedPort("/dev/shm/fastrtps_port42160", "/dev/shm"));  // the segment, not a lock
  CHECK_FALSE(ListenedPort("/dev/shm/sem.fastrtps_port42160_mutex", "/dev/shm"));
  CHECK_FALSE(ListenedPort("/dev/shm/fastrtps_portx_el", "/dev/shm"));
  CHECK_FALSE(ListenedPort("/dev/shm/fastrtps_port_el", "/dev/shm"));
  CHECK_FALSE(ListenedPort("/tmp/fastrtps_port42160_el", "/dev/shm"));
  CHECK_FALSE(ListenedPort("socket:[123456]", "/dev/shm"));
}

TEST_CASE("the inodes of a file's mappings, removed or not", "[dds][shm]") {
  const std::string maps =
      "7f00a000-7f00b000 rw-s 00000000 00:19 1201                       /dev/shm/fastrtps_port42160 (deleted)\n"
      "7f00c000-7f00d000 rw-s 00000000 00:19 1305                       /dev/shm/fastrtps_port42160\n"
      "7f00e000-7f00f000 rw-s 00000000 00:19 1306                       /dev/shm/fastrtps_port421600\n"
      "7f010000-7f011000 r--p 00000000 00:00 0 \n"
      "7f012000-7f013000 rw-s 00000000 00:19 1400                       /dev/shm/fastrtps_port42161\n";
  CHECK(MappedInodes(maps, "/dev/shm/fastrtps_port42160") == std::set<unsigned long>{1201, 1305});
  CHECK(MappedInodes(maps, "/dev/shm/fastrtps_port42161") == std::set<unsigned long>{1400});
  CHECK(MappedInodes(maps, "/dev/shm/fastrtps_port7400").empty());
  CHECK(MappedInodes("", "/dev/shm/fastrtps_port42160").empty());
}

TEST_CASE("a port whose segment a peer replaced is lost once it stays replaced", "[dds][shm]") {
  TempDir dir;
  const fs::path segment = dir.path / "fastrtps_port1234";
  const fs::path lock = dir.path / "fastrtps_port1234_el";
  const int lock_fd = ::open(lock.c_str(), O_RDONLY | O_CREAT, 0600);  // as the listener holds it
  REQUIRE(lock_fd >= 0);
  CHECK(ShmPortWatch::ListenedPorts(dir.path.string()) == std::vector<int>{1234});

  ShmPortWatch watch({1234}, 1.0, dir.path.string());
  {
    Mapped listened(segment);
    CHECK(watch.Replaced().empty());
    CHECK(watch.Lost(0.0).empty());

    // A peer removes the segment's name and creates a new segment under it.
    fs::remove(segment);
    CreateUnmapped(segment);  // the peer is another process: this one does not map it
    CHECK(watch.Replaced() == std::vector<int>{1234});
    CHECK(watch.Lost(10.0).empty());  // replaced since 10 s: not for a whole check yet
    CHECK(watch.Lost(10.5).empty());
    CHECK(watch.Lost(11.0) == std::vector<int>{1234});

    // Fast DDS moves its listener to the new segment: the port is read again.
    Mapped moved(segment);
    CHECK(watch.Replaced().empty());
    CHECK(watch.Lost(11.5).empty());
    CHECK(watch.Lost(20.0).empty());  // the hold starts again from the next replacement
  }
  // Unmapped and gone.
  fs::remove(segment);
  CHECK(watch.Replaced() == std::vector<int>{1234});
  CHECK(watch.Lost(30.0).empty());
  CHECK(watch.Lost(31.0) == std::vector<int>{1234});
  ::close(lock_fd);
  CHECK(ShmPortWatch::ListenedPorts(dir.path.string()).empty());
}

TEST_CASE("no port watched, none lost", "[dds][shm]") {
  ShmPortWatch watch({}, 0.0, "/nonexistent");
  CHECK(watch.Replaced().empty());
  CHECK(watch.Lost(100.0).empty());
}

namespace {

// A listener's hold of a port's lock file, as Fast DDS takes it (an exclusive flock on
// fastrtps_port<P>_el, its own open file description), until released or the scope ends.
struct HeldLock {
  int fd = -1;
  HeldLock(const fs::path& dir, int port) {
    const std::string path = (dir / ("fastrtps_port" + std::to_string(port) + "_el")).string();
    fd = ::open(path.c_str(), O_CREAT | O_RDONLY, 0666);
    REQUIRE(fd >= 0);
    REQUIRE(::flock(fd, LOCK_EX | LOCK_NB) == 0);
  }
  void Release() {
    if (fd >= 0) ::close(fd);  // as the kernel does when the process ends
    fd = -1;
  }
  ~HeldLock() { Release(); }
};

}  // namespace

TEST_CASE("a port's listener is held while its lock is, free after, absent without a file", "[dds][shm]") {
  using deif::dds::ListenerOf;
  using deif::dds::PortListener;
  TempDir dir;
  const std::string d = dir.path.string();
  CHECK(ListenerOf(7411, d) == PortListener::kAbsent);
  HeldLock lock(dir.path, 7411);
  CHECK(ListenerOf(7411, d) == PortListener::kHeld);
  CHECK(ListenerOf(7411, d) == PortListener::kHeld);  // the probe took nothing for good
  lock.Release();
  CHECK(ListenerOf(7411, d) == PortListener::kFree);
  // The probe left the file as it was: a listener can lock it again.
  HeldLock again(dir.path, 7411);
  CHECK(ListenerOf(7411, d) == PortListener::kHeld);
}

TEST_CASE("a process counts as ended once all its ports stay free for two checks, once", "[dds][shm]") {
  using Watch = deif::dds::BasicEndedProcessWatch<int>;
  TempDir dir;
  Watch watch(dir.path.string());
  HeldLock a1(dir.path, 7420), a2(dir.path, 7421), b1(dir.path, 7422), b2(dir.path, 7423);
  watch.Watch({{1, {7420, 7421}}, {2, {7422, 7423}}, {3, {7424, 7425}}});  // 3: not on this host
  CHECK(watch.Check().empty());
  a1.Release();  // one port free is not an end (the other is held)
  CHECK(watch.Check().empty());
  CHECK(watch.Check().empty());
  a2.Release();  // both free now
  CHECK(watch.Check().empty());                    // a first check: maybe a port made anew
  CHECK(watch.Check() == std::vector<int>{1});     // a second: ended
  CHECK(watch.Check().empty());                    // told once
  // A listener that makes its port anew lets go of the lock between two checks: not an end.
  b1.Release();
  b2.Release();
  CHECK(watch.Check().empty());
  HeldLock b1_again(dir.path, 7422), b2_again(dir.path, 7423);
  CHECK(watch.Check().empty());
  CHECK(watch.Check().empty());
  // Ports never seen held (another host's, whose numbers this host does not use) are never an end.
  CHECK(watch.Check().empty());
}

TEST_CASE("a process no longer watched is not reported; watched anew with other ports, it starts over",
          "[dds][shm]") {
  using Watch = deif::dds::BasicEndedProcessWatch<int>;
  TempDir dir;
  Watch watch(dir.path.string());
  HeldLock a(dir.path, 7430);
  watch.Watch({{1, {7430}}});
  CHECK(watch.Check().empty());
  a.Release();
  CHECK(watch.Check().empty());
  watch.Watch({});  // its participant is gone by the lease already
  CHECK(watch.Check().empty());
  CHECK(watch.Check().empty());
  HeldLock b(dir.path, 7431);
  watch.Watch({{1, {7431}}});
  CHECK(watch.Check().empty());
  b.Release();
  CHECK(watch.Check().empty());
  CHECK(watch.Check() == std::vector<int>{1});
}

TEST_CASE("a check of some participants probes and reports those alone", "[dds][shm]") {
  using Watch = deif::dds::BasicEndedProcessWatch<int>;
  TempDir dir;
  Watch watch(dir.path.string());
  HeldLock a(dir.path, 7440), b(dir.path, 7441);
  watch.Watch({{1, {7440}}, {2, {7441}}});
  CHECK(watch.Check().empty());
  a.Release();
  b.Release();
  CHECK(watch.Check({1}).empty());
  CHECK(watch.Check({1}) == std::vector<int>{1});  // 2 was not probed: one free look so far
  CHECK(watch.Check().empty());
  CHECK(watch.Check() == std::vector<int>{2});
}

TEST_CASE("a participant another process already found ended takes one free look", "[dds][shm]") {
  using Watch = deif::dds::BasicEndedProcessWatch<int>;
  TempDir dir;
  Watch watch(dir.path.string());
  HeldLock a(dir.path, 7450);
  watch.Watch({{1, {7450}}});
  CHECK(watch.Check({1}, 1).empty());  // held
  a.Release();
  CHECK(watch.Check({1}, 1) == std::vector<int>{1});
}
