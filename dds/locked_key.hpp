// A fastddsgen type support whose key hashes are safe to compute on several threads at once.
#pragma once

#include <mutex>

#include <fastdds/rtps/common/InstanceHandle.h>

namespace deif::dds {

// fastddsgen's type support computes a sample's key hash in buffers it owns (one key buffer
// and one MD5 context per registered type) without a lock, and Fast DDS calls getKey from
// the writing thread and from its receive threads at once. With security every key hash is
// an MD5 (the key is not sent in clear), and two computations at once corrupt it: the sample
// is put in an instance of its own, and once a reader holds max_instances instances, Fast
// DDS marks a sample that needs a new one irrelevant, which loses it for good, repairs
// included (docs/FASTDDS_NOTES.md, "Key hashes"). One lock per type support.
template <typename Generated>
class LockedKey final : public Generated {
 public:
  bool getKey(void* data, eprosima::fastrtps::rtps::InstanceHandle_t* handle, bool force_md5) override {
    std::lock_guard<std::mutex> lock(mutex_);
    return Generated::getKey(data, handle, force_md5);
  }

 private:
  std::mutex mutex_;
};

}  // namespace deif::dds
