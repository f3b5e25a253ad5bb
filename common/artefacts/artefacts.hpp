// The run artefacts (docs/ARTEFACTS.md): CSV files written one row at a time and flushed at
// once, so that a process killed with -9 loses at most the step in flight; and readers of
// the same files for the replay and the metrics. Each file's columns are declared once, in
// the schema tables below; the writers, the readers and the docs follow them.
#pragma once

#include <cstdio>
#include <optional>
#include <string>
#include <vector>

#include "common/core/types.hpp"

namespace deif {

// One CSV file: its name and its columns, in order.
struct CsvSchema {
  const char* file_name;  // "agent_<id>.csv" for the per-agent file
  std::vector<const char*> columns;
  std::string Header() const;  // the columns joined by commas
};

extern const CsvSchema kTargetCsvSchema;  // target.csv
extern const CsvSchema kRangesCsvSchema;  // ranges.csv
extern const CsvSchema kAgentCsvSchema;   // agent_<id>.csv

enum class CsvMode {
  kTruncate,  // a new file: header first
  kAppend,    // a restarted process: keep the rows, header only if the file is empty
};

// A CSV file written one row at a time; every row is flushed to the OS when written.
class CsvWriter {
 public:
  CsvWriter() = default;
  // Opens path and writes the header when the file is new (or empty). Throws
  // std::runtime_error naming the path if it cannot be opened.
  CsvWriter(const std::string& path, const std::string& header, CsvMode mode = CsvMode::kTruncate);
  ~CsvWriter();
  CsvWriter(CsvWriter&& other) noexcept;
  CsvWriter& operator=(CsvWriter&& other) noexcept;
  CsvWriter(const CsvWriter&) = delete;
  CsvWriter& operator=(const CsvWriter&) = delete;

  bool is_open() const { return file_ != nullptr; }
  void WriteLine(const std::string& line);  // appends '\n' and flushes

 private:
  std::FILE* file_ = nullptr;
  std::string path_;
};

// Shortest decimal text that reads back to the same double ("%.17g").
std::string FormatDouble(double value);

struct TargetRow {
  StepIndex step = 0;
  double t_s = 0.0;
  Vector2 p_true = Vector2::Zero();
};

struct RangeRow {
  StepIndex step = 0;
  AgentId agent_id = 0;
  double range_m = 0.0;
  double variance_m2 = 0.0;
  Vector2 p_sensor = Vector2::Zero();
};

struct AgentRow {
  StepIndex step = 0;
  double t_s = 0.0;
  Vector2 estimate_m = Vector2::Zero();
  Matrix2 covariance = Matrix2::Zero();
  Vector2 position_m = Vector2::Zero();
  double angle_rad = 0.0;
  int alive = 0;
  int fused = 0;
  long rejected = 0;         // invalid peer messages so far (cumulative)
  long dropped = 0;          // valid but unusable (too old, too far ahead, duplicate), cumulative
  long late = 0;             // contributions fused after their step was written, cumulative
  long deadline_misses = 0;  // steps written without every contribution of the roll call
  bool complete = false;     // this row's sum held every contribution of the roll call
};

// target.csv
class TargetCsv {
 public:
  explicit TargetCsv(const std::string& path, CsvMode mode = CsvMode::kTruncate);
  void Write(const TargetRow& row);

 private:
  CsvWriter writer_;
};

// ranges.csv
class RangesCsv {
 public:
  explicit RangesCsv(const std::string& path, CsvMode mode = CsvMode::kTruncate);
  void Write(const RangeRow& row);

 private:
  CsvWriter writer_;
};

// agent_<id>.csv
class AgentCsv {
 public:
  explicit AgentCsv(const std::string& path, CsvMode mode = CsvMode::kTruncate);
  void Write(const AgentRow& row);

 private:
  CsvWriter writer_;
};

std::string AgentCsvName(AgentId id);  // "agent_<id>.csv"

// Readers. A missing file gives no rows; a torn final line (a process killed while writing)
// is ignored; any other malformed line throws std::runtime_error naming file and line.
// Files written by older versions with fewer trailing agent columns read with defaults.
std::vector<TargetRow> ReadTargetCsv(const std::string& path);
std::vector<RangeRow> ReadRangesCsv(const std::string& path);
std::vector<AgentRow> ReadAgentCsv(const std::string& path);

}  // namespace deif
