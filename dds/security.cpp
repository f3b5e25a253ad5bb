// DDS Security for dds::Node (security.hpp; docs/SECURITY.md). The checks use OpenSSL's C
// API the way Fast DDS's builtin plugins use it: X509_verify_cert for the identity, and
// PKCS7_verify with the CA as the only trusted certificate for the S/MIME documents.
#include "dds/security.hpp"

#include <openssl/bio.h>
#include <openssl/err.h>
#include <openssl/evp.h>
#include <openssl/pem.h>
#include <openssl/pkcs7.h>
#include <openssl/x509.h>
#include <openssl/x509_vfy.h>

#include <cerrno>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <memory>
#include <sstream>

namespace deif::dds {

namespace {

namespace fs = std::filesystem;

// OpenSSL objects with their free functions.
struct BioFree {
  void operator()(BIO* p) const { BIO_free(p); }
};
struct X509Free {
  void operator()(X509* p) const { X509_free(p); }
};
struct KeyFree {
  void operator()(EVP_PKEY* p) const { EVP_PKEY_free(p); }
};
struct StoreFree {
  void operator()(X509_STORE* p) const { X509_STORE_free(p); }
};
struct StoreCtxFree {
  void operator()(X509_STORE_CTX* p) const { X509_STORE_CTX_free(p); }
};
struct Pkcs7Free {
  void operator()(PKCS7* p) const { PKCS7_free(p); }
};
using Bio = std::unique_ptr<BIO, BioFree>;
using Cert = std::unique_ptr<X509, X509Free>;
using Key = std::unique_ptr<EVP_PKEY, KeyFree>;
using Store = std::unique_ptr<X509_STORE, StoreFree>;
using StoreCtx = std::unique_ptr<X509_STORE_CTX, StoreCtxFree>;
using Pkcs7 = std::unique_ptr<PKCS7, Pkcs7Free>;

[[noreturn]] void Fail(const std::string& file, const std::string& reason) {
  throw SecurityError(file + ": " + reason);
}

// The most recent OpenSSL error as text (and the queue cleared), or `otherwise`.
std::string OpenSslReason(const std::string& otherwise) {
  unsigned long code = 0;
  unsigned long last = 0;
  while ((code = ERR_get_error()) != 0) last = code;
  if (last == 0) return otherwise;
  const char* reason = ERR_reason_error_string(last);
  return reason != nullptr ? reason : otherwise;
}

void RequireReadable(const std::string& file, const char* what) {
  std::error_code ec;
  if (!fs::exists(file, ec)) Fail(file, std::string("missing (") + what + ")");
  if (!fs::is_regular_file(file, ec)) Fail(file, std::string("is not a file (") + what + ")");
  std::ifstream in(file, std::ios::binary);
  if (!in) Fail(file, std::string("cannot be read: ") + std::strerror(errno));
}

Bio OpenFile(const std::string& file) {
  Bio bio(BIO_new_file(file.c_str(), "r"));
  if (!bio) Fail(file, "cannot be read: " + OpenSslReason("open failed"));
  return bio;
}

std::string NameOf(const X509_NAME* name) {
  // RFC 2253, as Fast DDS prints a certificate's subject to compare it with a grant's.
  Bio out(BIO_new(BIO_s_mem()));
  X509_NAME_print_ex(out.get(), name, 0, XN_FLAG_RFC2253 & ~ASN1_STRFLGS_ESC_MSB);
  char* data = nullptr;
  const long length = BIO_get_mem_data(out.get(), &data);
  return length > 0 ? std::string(data, static_cast<std::size_t>(length)) : std::string();
}

std::string TimeText(const ASN1_TIME* time) {
  std::tm tm{};
  if (time == nullptr || ASN1_TIME_to_tm(time, &tm) != 1) return "?";
  std::ostringstream out;
  out << std::put_time(&tm, "%Y-%m-%d %H:%M:%S UTC");
  return out.str();
}

Cert ReadCertificate(const std::string& file, const char* what) {
  RequireReadable(file, what);
  Bio bio = OpenFile(file);
  Cert cert(PEM_read_bio_X509(bio.get(), nullptr, nullptr, nullptr));
  if (!cert) Fail(file, "not a PEM certificate (" + OpenSslReason("unreadable") + ")");
  return cert;
}

void CheckDates(const std::string& file, const X509* cert) {
  if (X509_cmp_current_time(X509_get0_notBefore(cert)) > 0) {
    Fail(file, "not valid before " + TimeText(X509_get0_notBefore(cert)));
  }
  if (X509_cmp_current_time(X509_get0_notAfter(cert)) < 0) {
    Fail(file, "expired on " + TimeText(X509_get0_notAfter(cert)));
  }
}

// The identity certificate against the CA, as PKI-DH verifies it.
void VerifyIssuedBy(const std::string& file, X509* cert, X509_STORE* store, const std::string& ca_file,
                    const X509* ca) {
  StoreCtx ctx(X509_STORE_CTX_new());
  if (!ctx || X509_STORE_CTX_init(ctx.get(), store, cert, nullptr) != 1) {
    Fail(file, "cannot verify: " + OpenSslReason("out of memory"));
  }
  X509_STORE_CTX_set_flags(ctx.get(), X509_V_FLAG_CHECK_SS_SIGNATURE);
  if (X509_verify_cert(ctx.get()) == 1) return;
  const int error = X509_STORE_CTX_get_error(ctx.get());
  switch (error) {
    case X509_V_ERR_CERT_HAS_EXPIRED:
      Fail(file, "expired on " + TimeText(X509_get0_notAfter(cert)));
    case X509_V_ERR_CERT_NOT_YET_VALID:
      Fail(file, "not valid before " + TimeText(X509_get0_notBefore(cert)));
    case X509_V_ERR_UNABLE_TO_GET_ISSUER_CERT_LOCALLY:
    case X509_V_ERR_UNABLE_TO_GET_ISSUER_CERT:
    case X509_V_ERR_CERT_SIGNATURE_FAILURE:
    case X509_V_ERR_DEPTH_ZERO_SELF_SIGNED_CERT:
      Fail(file, "not issued by the CA of " + ca_file + " (issuer '" +
                     NameOf(X509_get_issuer_name(cert)) + "', CA '" +
                     NameOf(X509_get_subject_name(ca)) + "')");
    default:
      Fail(file, std::string("does not verify against ") + ca_file + ": " +
                     X509_verify_cert_error_string(error));
  }
}

// A PEM private key; an encrypted one is refused (nobody could type its password).
Key ReadKey(const std::string& file) {
  RequireReadable(file, "the private key");
  Bio bio = OpenFile(file);
  pem_password_cb* no_password = [](char*, int, int, void*) { return 0; };
  Key key(PEM_read_bio_PrivateKey(bio.get(), nullptr, no_password, nullptr));
  if (!key) {
    Fail(file, "not an unencrypted PEM private key (" + OpenSslReason("unreadable") + ")");
  }
  return key;
}

// An S/MIME document signed by the CA; returns its signed text.
std::string VerifySigned(const std::string& file, const char* what, X509_STORE* store,
                         const std::string& ca_file) {
  RequireReadable(file, what);
  Bio in = OpenFile(file);
  BIO* content = nullptr;
  Pkcs7 p7(SMIME_read_PKCS7(in.get(), &content));
  Bio content_owner(content);
  if (!p7) {
    Fail(file, std::string("not an S/MIME signed document (") + what +
                   " must be signed by the CA: scripts/deif-certs; " + OpenSslReason("unreadable") +
                   ")");
  }
  Bio out(BIO_new(BIO_s_mem()));
  if (PKCS7_verify(p7.get(), nullptr, store, content, out.get(), PKCS7_TEXT) != 1) {
    Fail(file, "its signature does not verify against the CA of " + ca_file + " (" +
                   OpenSslReason("bad signature") + ")");
  }
  char* data = nullptr;
  const long length = BIO_get_mem_data(out.get(), &data);
  return length > 0 ? std::string(data, static_cast<std::size_t>(length)) : std::string();
}

// The text of every <tag>...</tag> in `xml` from `from` on, up to `to`.
std::vector<std::string> Elements(const std::string& xml, const std::string& tag, std::size_t from = 0,
                                  std::size_t to = std::string::npos) {
  std::vector<std::string> out;
  const std::string open = "<" + tag;
  const std::string close = "</" + tag + ">";
  for (std::size_t at = xml.find(open, from); at != std::string::npos && at < to;
       at = xml.find(open, at + 1)) {
    const char next = at + open.size() < xml.size() ? xml[at + open.size()] : '\0';
    if (next != '>' && next != ' ' && next != '\t' && next != '\n' && next != '\r') continue;
    const std::size_t body = xml.find('>', at);
    const std::size_t end = xml.find(close, at);
    if (body == std::string::npos || end == std::string::npos || end > to) break;
    out.push_back(xml.substr(body + 1, end - body - 1));
  }
  return out;
}

std::string Trim(const std::string& text) {
  const std::size_t first = text.find_first_not_of(" \t\r\n");
  if (first == std::string::npos) return "";
  return text.substr(first, text.find_last_not_of(" \t\r\n") - first + 1);
}

// Two RFC 2253 names are equal attribute by attribute, blanks about each ignored (as
// Fast DDS compares a grant's subject_name with a certificate's subject).
bool SameName(const std::string& a, const std::string& b) {
  const auto parts = [](const std::string& text) {
    std::vector<std::string> out;
    std::istringstream in(text);
    std::string part;
    while (std::getline(in, part, ',')) out.push_back(Trim(part));
    return out;
  };
  return parts(a) == parts(b);
}

// A grant's validity, read as Fast DDS reads it (local time, std::get_time "%Y-%m-%dT%T").
std::optional<std::time_t> GrantTime(const std::string& text) {
  std::tm tm{};
  std::istringstream in(Trim(text));
  in >> std::get_time(&tm, "%Y-%m-%dT%T");
  if (in.fail()) return std::nullopt;
  return std::mktime(&tm);
}

void CheckPermissions(const std::string& file, const std::string& xml, const std::string& subject,
                      const std::string& certificate) {
  if (xml.find("<permissions") == std::string::npos) {
    Fail(file, "signed, but not a permissions document (no <permissions>)");
  }
  const std::time_t now = std::time(nullptr);
  std::string late;
  for (std::size_t at = xml.find("<grant"); at != std::string::npos; at = xml.find("<grant", at + 1)) {
    const std::size_t end = xml.find("</grant>", at);
    const std::vector<std::string> names = Elements(xml, "subject_name", at, end);
    if (names.empty() || !SameName(Trim(names.front()), subject)) continue;
    const std::vector<std::string> before = Elements(xml, "not_before", at, end);
    const std::vector<std::string> after = Elements(xml, "not_after", at, end);
    const auto from = before.empty() ? std::nullopt : GrantTime(before.front());
    const auto until = after.empty() ? std::nullopt : GrantTime(after.front());
    if (!from || !until) {
      late = "its grant for '" + subject + "' has no readable validity (YYYY-MM-DDThh:mm:ss)";
    } else if (now < *from) {
      late = "its grant for '" + subject + "' is not valid before " + Trim(before.front());
    } else if (now > *until) {
      late = "its grant for '" + subject + "' expired on " + Trim(after.front());
    } else {
      return;  // a grant in time
    }
  }
  if (!late.empty()) Fail(file, late);
  Fail(file, "grants nothing to '" + subject + "', the subject of " + certificate);
}

std::string FileUri(const std::string& path) { return "file://" + path; }

}  // namespace

SecurityFiles FilesOf(const std::string& dir, const std::string& name) {
  std::error_code ec;
  fs::path base = fs::absolute(fs::path(dir), ec);
  if (ec) base = fs::path(dir);
  base = base.lexically_normal();
  SecurityFiles files;
  files.ca = (base / "ca.pem").string();
  files.governance = (base / "governance.p7s").string();
  files.certificate = (base / (name + ".cert.pem")).string();
  files.private_key = (base / (name + ".key.pem")).string();
  files.permissions = (base / (name + ".permissions.p7s")).string();
  return files;
}

void CheckSecurityFiles(const SecurityFiles& files) {
  ERR_clear_error();
  Cert ca = ReadCertificate(files.ca, "the CA certificate");
  CheckDates(files.ca, ca.get());
  Store store(X509_STORE_new());
  if (!store || X509_STORE_add_cert(store.get(), ca.get()) != 1) {
    Fail(files.ca, "cannot be used as a CA: " + OpenSslReason("out of memory"));
  }

  Cert cert = ReadCertificate(files.certificate, "this process's identity certificate");
  VerifyIssuedBy(files.certificate, cert.get(), store.get(), files.ca, ca.get());
  Key key = ReadKey(files.private_key);
  if (X509_check_private_key(cert.get(), key.get()) != 1) {
    ERR_clear_error();
    Fail(files.private_key, "is not the key of the certificate " + files.certificate);
  }

  const std::string governance =
      VerifySigned(files.governance, "the governance", store.get(), files.ca);
  if (governance.find("<domain_access_rules") == std::string::npos) {
    Fail(files.governance, "signed, but not a governance document (no <domain_access_rules>)");
  }
  const std::string permissions =
      VerifySigned(files.permissions, "the permissions", store.get(), files.ca);
  CheckPermissions(files.permissions, permissions, NameOf(X509_get_subject_name(cert.get())),
                   files.certificate);
}

std::vector<std::pair<std::string, std::string>> SecurityProperties(const SecurityFiles& files) {
  return {
      {"dds.sec.auth.plugin", "builtin.PKI-DH"},
      {"dds.sec.auth.builtin.PKI-DH.identity_ca", FileUri(files.ca)},
      {"dds.sec.auth.builtin.PKI-DH.identity_certificate", FileUri(files.certificate)},
      {"dds.sec.auth.builtin.PKI-DH.private_key", FileUri(files.private_key)},
      {"dds.sec.access.plugin", "builtin.Access-Permissions"},
      {"dds.sec.access.builtin.Access-Permissions.permissions_ca", FileUri(files.ca)},
      {"dds.sec.access.builtin.Access-Permissions.governance", FileUri(files.governance)},
      {"dds.sec.access.builtin.Access-Permissions.permissions", FileUri(files.permissions)},
      {"dds.sec.crypto.plugin", "builtin.AES-GCM-GMAC"},
  };
}

std::string PublisherPartition(const std::string& run_name, const std::string& name) {
  const std::string agent = "agent-";
  if (name.compare(0, agent.size(), agent) == 0 && name.size() > agent.size()) {
    return "deif." + run_name + ".agent." + name.substr(agent.size());
  }
  return "deif." + run_name + "." + name;
}

std::string SubscriberPartition(const std::string& run_name) { return "deif." + run_name + ".*"; }

std::optional<AgentId> AuthorizedAgentOf(const std::vector<std::string>& partitions,
                                         const std::string& run_name) {
  const std::string prefix = "deif." + run_name + ".agent.";
  std::optional<AgentId> id;
  for (const std::string& partition : partitions) {
    if (partition.compare(0, prefix.size(), prefix) != 0) continue;
    const std::string digits = partition.substr(prefix.size());
    if (digits.empty() || digits.size() > 9 || digits[0] == '0' ||
        digits.find_first_not_of("0123456789") != std::string::npos) {
      continue;
    }
    const auto j = static_cast<AgentId>(std::stol(digits));
    if (id && *id != j) return std::nullopt;  // two ids: neither (permissions never allow it)
    id = j;
  }
  return id;
}

}  // namespace deif::dds
