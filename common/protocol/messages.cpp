#include "common/protocol/messages.hpp"

#include <algorithm>
#include <cstdio>

namespace deif::protocol {

RunToken RunTokenOf(const std::string& run_name) {
  std::uint64_t hash = 14695981039346656037ull;  // FNV-1a offset basis
  for (const unsigned char c : run_name) {
    hash ^= c;
    hash *= 1099511628211ull;  // FNV prime
  }
  return hash == 0 ? 1 : hash;
}

bool SameProcess(const SenderKey& a, const SenderKey& b) {
  return std::equal(a.begin(), a.begin() + 12, b.begin());
}

std::string ToString(const SenderKey& key) {
  std::string out;
  char byte[3];
  for (std::size_t i = 0; i < key.size(); ++i) {
    std::snprintf(byte, sizeof byte, "%02x", key[i]);
    out += byte;
    if (i == 11) out += '|';
  }
  return out;
}

}  // namespace deif::protocol
