// The run artefacts (docs/ARTEFACTS.md): one CSV row per step, flushed at once.
#include "common/artefacts/artefacts.hpp"

#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <utility>

namespace deif {

const CsvSchema kTargetCsvSchema{"target.csv", {"step", "t", "x_true", "y_true"}};
const CsvSchema kRangesCsvSchema{"ranges.csv",
                                 {"step", "agent_id", "range", "variance", "sensor_x", "sensor_y"}};
// The first 13 columns are the contract of the run-artefact format; the rest are extras.
const CsvSchema kAgentCsvSchema{
    "agent_<id>.csv",
    {"step", "t", "x_est", "y_est", "p_xx", "p_xy", "p_yy", "pos_x", "pos_y", "angle", "alive",
     "fused", "rejected", "dropped", "late", "misses", "complete"}};

std::string CsvSchema::Header() const {
  std::string header;
  for (const char* column : columns) {
    if (!header.empty()) header += ',';
    header += column;
  }
  return header;
}

CsvWriter::CsvWriter(const std::string& path, const std::string& header, CsvMode mode)
    : path_(path) {
  file_ = std::fopen(path.c_str(), mode == CsvMode::kAppend ? "a" : "w");
  if (file_ == nullptr) {
    throw std::runtime_error("cannot open '" + path + "' for writing: " + std::strerror(errno));
  }
  if (std::ftell(file_) == 0) WriteLine(header);
}

CsvWriter::~CsvWriter() {
  if (file_ != nullptr) std::fclose(file_);
}

CsvWriter::CsvWriter(CsvWriter&& other) noexcept
    : file_(std::exchange(other.file_, nullptr)), path_(std::move(other.path_)) {}

CsvWriter& CsvWriter::operator=(CsvWriter&& other) noexcept {
  if (this != &other) {
    if (file_ != nullptr) std::fclose(file_);
    file_ = std::exchange(other.file_, nullptr);
    path_ = std::move(other.path_);
  }
  return *this;
}

void CsvWriter::WriteLine(const std::string& line) {
  if (file_ == nullptr) throw std::logic_error("CsvWriter: write to a closed file");
  // One row per call, flushed to the OS, so a kill -9 loses at most the step in flight.
  if (std::fputs(line.c_str(), file_) < 0 || std::fputc('\n', file_) == EOF ||
      std::fflush(file_) != 0) {
    throw std::runtime_error("cannot write to '" + path_ + "': " + std::strerror(errno));
  }
}

std::string FormatDouble(double value) {
  char buffer[32];
  std::snprintf(buffer, sizeof(buffer), "%.17g", value);
  return buffer;
}

namespace {

// Joins fields with commas; each row type lists its fields in its schema's column order.
class Row {
 public:
  Row& operator<<(double v) { return Add(FormatDouble(v)); }
  Row& operator<<(long long v) { return Add(std::to_string(v)); }
  Row& operator<<(long v) { return Add(std::to_string(v)); }
  Row& operator<<(int v) { return Add(std::to_string(v)); }
  Row& operator<<(bool v) { return Add(v ? "1" : "0"); }
  const std::string& str() const { return text_; }
  int fields() const { return fields_; }

 private:
  Row& Add(const std::string& field) {
    if (fields_++ > 0) text_ += ',';
    text_ += field;
    return *this;
  }
  std::string text_;
  int fields_ = 0;
};

void WriteRow(CsvWriter& writer, const CsvSchema& schema, const Row& row) {
  if (row.fields() != static_cast<int>(schema.columns.size())) {
    throw std::logic_error(std::string("row of ") + schema.file_name + " has the wrong field count");
  }
  writer.WriteLine(row.str());
}

}  // namespace

TargetCsv::TargetCsv(const std::string& path, CsvMode mode)
    : writer_(path, kTargetCsvSchema.Header(), mode) {}

void TargetCsv::Write(const TargetRow& r) {
  Row row;
  row << static_cast<long long>(r.step) << r.t_s << r.p_true.x() << r.p_true.y();
  WriteRow(writer_, kTargetCsvSchema, row);
}

RangesCsv::RangesCsv(const std::string& path, CsvMode mode)
    : writer_(path, kRangesCsvSchema.Header(), mode) {}

void RangesCsv::Write(const RangeRow& r) {
  Row row;
  row << static_cast<long long>(r.step) << r.agent_id << r.range_m << r.variance_m2
      << r.p_sensor.x() << r.p_sensor.y();
  WriteRow(writer_, kRangesCsvSchema, row);
}

AgentCsv::AgentCsv(const std::string& path, CsvMode mode)
    : writer_(path, kAgentCsvSchema.Header(), mode) {}

void AgentCsv::Write(const AgentRow& r) {
  Row row;
  row << static_cast<long long>(r.step) << r.t_s << r.estimate_m.x() << r.estimate_m.y()
      << r.covariance(0, 0) << r.covariance(0, 1) << r.covariance(1, 1) << r.position_m.x()
      << r.position_m.y() << r.angle_rad << r.alive << r.fused << r.rejected << r.dropped
      << r.late << r.deadline_misses << r.complete;
  WriteRow(writer_, kAgentCsvSchema, row);
}

std::string AgentCsvName(AgentId id) { return "agent_" + std::to_string(id) + ".csv"; }

// ---------------------------------------------------------------------------------------
// Readers

namespace {

// Reads a CSV with the given schema; calls parse(fields, line_no) for each complete row.
// Accepts files whose header is a prefix of the schema's (older files with fewer extras).
template <typename Parse>
void ReadCsv(const std::string& path, const CsvSchema& schema, std::size_t min_columns,
             Parse parse) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return;
  std::stringstream buffer;
  buffer << in.rdbuf();
  const std::string text = buffer.str();
  std::size_t pos = 0;
  int line_no = 0;
  std::size_t columns = 0;
  while (pos < text.size()) {
    const std::size_t end = text.find('\n', pos);
    if (end == std::string::npos) break;  // a torn final row: the writer died mid-line
    const std::string line = text.substr(pos, end - pos);
    pos = end + 1;
    ++line_no;
    std::vector<std::string> fields;
    std::stringstream stream(line);
    for (std::string field; std::getline(stream, field, ',');) fields.push_back(field);
    if (line_no == 1) {
      columns = fields.size();
      bool prefix = columns >= min_columns && columns <= schema.columns.size();
      for (std::size_t i = 0; prefix && i < columns; ++i) prefix = fields[i] == schema.columns[i];
      if (!prefix) {
        throw std::runtime_error(path + ":1: unexpected header '" + line + "' (expected '" +
                                 schema.Header() + "')");
      }
      continue;
    }
    if (line.empty()) continue;
    if (fields.size() != columns) {
      throw std::runtime_error(path + ":" + std::to_string(line_no) + ": expected " +
                               std::to_string(columns) + " fields");
    }
    try {
      parse(fields, line_no);
    } catch (const std::logic_error&) {  // std::stod / stoll: invalid_argument, out_of_range
      throw std::runtime_error(path + ":" + std::to_string(line_no) + ": not a number");
    }
  }
}

double D(const std::string& s) { return std::stod(s); }
long long I(const std::string& s) { return std::stoll(s); }

}  // namespace

std::vector<TargetRow> ReadTargetCsv(const std::string& path) {
  std::vector<TargetRow> rows;
  ReadCsv(path, kTargetCsvSchema, kTargetCsvSchema.columns.size(),
          [&](const std::vector<std::string>& f, int) {
            rows.push_back({I(f[0]), D(f[1]), Vector2(D(f[2]), D(f[3]))});
          });
  return rows;
}

std::vector<RangeRow> ReadRangesCsv(const std::string& path) {
  std::vector<RangeRow> rows;
  ReadCsv(path, kRangesCsvSchema, kRangesCsvSchema.columns.size(),
          [&](const std::vector<std::string>& f, int) {
            RangeRow r;
            r.step = I(f[0]);
            r.agent_id = static_cast<AgentId>(I(f[1]));
            r.range_m = D(f[2]);
            r.variance_m2 = D(f[3]);
            r.p_sensor = Vector2(D(f[4]), D(f[5]));
            rows.push_back(r);
          });
  return rows;
}

std::vector<AgentRow> ReadAgentCsv(const std::string& path) {
  std::vector<AgentRow> rows;
  ReadCsv(path, kAgentCsvSchema, 13, [&](const std::vector<std::string>& f, int) {
    AgentRow r;
    r.step = I(f[0]);
    r.t_s = D(f[1]);
    r.estimate_m = Vector2(D(f[2]), D(f[3]));
    r.covariance << D(f[4]), D(f[5]), D(f[5]), D(f[6]);
    r.position_m = Vector2(D(f[7]), D(f[8]));
    r.angle_rad = D(f[9]);
    r.alive = static_cast<int>(I(f[10]));
    r.fused = static_cast<int>(I(f[11]));
    r.rejected = static_cast<long>(I(f[12]));
    if (f.size() > 13) r.dropped = static_cast<long>(I(f[13]));
    if (f.size() > 14) r.late = static_cast<long>(I(f[14]));
    if (f.size() > 15) r.deadline_misses = static_cast<long>(I(f[15]));
    if (f.size() > 16) r.complete = I(f[16]) != 0;
    rows.push_back(r);
  });
  return rows;
}

}  // namespace deif
