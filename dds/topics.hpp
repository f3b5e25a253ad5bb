// The topics of the network (a contract: docs/ARCHITECTURE.md), with their ROS 2 names for
// network.ros2_naming (docs/ROS2.md).
#pragma once

namespace deif::dds {

enum class Topic { kTruth, kRange, kContribution, kAgentState, kRelayUp, kRelayDown };
inline constexpr Topic kAllTopics[] = {Topic::kTruth,      Topic::kRange,   Topic::kContribution,
                                       Topic::kAgentState, Topic::kRelayUp, Topic::kRelayDown};

struct TopicNames {
  const char* name;       // "deif/range"
  const char* ros2_name;  // "rt/deif/range"
  const char* type;       // the IDL type, as fastddsgen names it
  const char* ros2_type;  // the ROS 2 DDS type name
};

constexpr TopicNames NamesOf(Topic topic) {
  switch (topic) {
    case Topic::kTruth:
      return {"deif/truth", "rt/deif/truth", "deif_msgs::Truth", "deif_msgs::msg::dds_::Truth_"};
    case Topic::kRange:
      return {"deif/range", "rt/deif/range", "deif_msgs::Range", "deif_msgs::msg::dds_::Range_"};
    case Topic::kContribution:
      return {"deif/contribution", "rt/deif/contribution", "deif_msgs::Contribution",
              "deif_msgs::msg::dds_::Contribution_"};
    case Topic::kAgentState:
      return {"deif/agent_state", "rt/deif/agent_state", "deif_msgs::AgentState",
              "deif_msgs::msg::dds_::AgentState_"};
    case Topic::kRelayUp:
      return {"deif/relay_up", "rt/deif/relay_up", "deif_msgs::ContributionBatch",
              "deif_msgs::msg::dds_::ContributionBatch_"};
    case Topic::kRelayDown:
      return {"deif/relay_down", "rt/deif/relay_down", "deif_msgs::ContributionBatch",
              "deif_msgs::msg::dds_::ContributionBatch_"};
  }
  return {"", "", "", ""};
}

}  // namespace deif::dds
