// DDS Security for dds::Node (docs/SECURITY.md): where one participant's security files
// are, their checks at start, the Fast DDS participant properties that switch the builtin
// plugins on, and the partitions that carry each publisher's role.
//
// Roles are partitions. A process publishes in deif.<run>.target (the target) or
// deif.<run>.agent.<J> (agent J) and subscribes to deif.<run>.*; the permissions the CA
// signed for agent J allow it to publish contributions and states only in partitions
// matching deif.*.agent.J, and nothing on the truth or the ranges. Every receiver checks a
// remote writer's partitions against the permissions of its participant before it matches
// it (Fast DDS, check_remote_datawriter), so a matched writer's partition says which agent
// id it may speak for: AuthorizedAgentOf.
#pragma once

#include <optional>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "common/core/types.hpp"

namespace deif::dds {

// A security file that is missing or bad. what() is one line: the file, then the reason.
class SecurityError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// The files one participant uses, as absolute paths.
struct SecurityFiles {
  std::string ca;           // ca.pem: the identity CA, also the permissions CA
  std::string governance;   // governance.p7s: the domain's rules, signed by the CA
  std::string certificate;  // <name>.cert.pem: this participant's identity
  std::string private_key;  // <name>.key.pem
  std::string permissions;  // <name>.permissions.p7s: what this identity may do, signed
};

// The files of the participant called `name` (target, agent-<id>, observer-<m>) in `dir`.
SecurityFiles FilesOf(const std::string& dir, const std::string& name);

// Checks the files the way the builtin plugins will use them, and says why where Fast DDS
// would only fail to create the participant (or, for a foreign CA, silently never match):
// every file present and readable; the CA a valid certificate; the identity certificate
// issued by that CA and within its dates; the private key readable (unencrypted) and the
// certificate's; the governance and the permissions S/MIME documents signed by the CA; the
// permissions grant the certificate's subject and are within their dates. Throws
// SecurityError naming the first bad file.
void CheckSecurityFiles(const SecurityFiles& files);

// The participant properties that enable PKI-DH, Access-Permissions and AES-GCM-GMAC with
// these files (file:// URIs).
std::vector<std::pair<std::string, std::string>> SecurityProperties(const SecurityFiles& files);

// The partition a participant called `name` publishes in: deif.<run>.target,
// deif.<run>.agent.<J> for agent-<J>, deif.<run>.<name> for anything else.
std::string PublisherPartition(const std::string& run_name, const std::string& name);
// The partition every participant of the run subscribes to: deif.<run>.* (a wildcard).
std::string SubscriberPartition(const std::string& run_name);
// The agent id a writer in `partitions` may speak for: J when one of them is exactly
// deif.<run>.agent.<J>; nullopt otherwise (the target, an observer, another run).
std::optional<AgentId> AuthorizedAgentOf(const std::vector<std::string>& partitions,
                                         const std::string& run_name);

}  // namespace deif::dds
