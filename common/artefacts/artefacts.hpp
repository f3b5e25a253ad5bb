// The run artefacts of DESIGN.md: CSV files flushed row by row, so that a process killed
// with -9 loses at most the step in flight.
#pragma once

#include <cstdio>
#include <string>

#include "common/core/types.hpp"

namespace deif {

// A CSV file written one row at a time; every row is flushed to the OS when written.
class CsvWriter {
 public:
  CsvWriter() = default;
  // Creates (truncates) path and writes the header line. Throws std::runtime_error naming
  // the path if it cannot be opened.
  CsvWriter(const std::string& path, const std::string& header);
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
  long rejected = 0;  // peer contributions rejected so far (cumulative)
  long dropped = 0;   // extra column: late / duplicate / out-of-window, cumulative
};

// target.csv: step,t,x_true,y_true
class TargetCsv {
 public:
  explicit TargetCsv(const std::string& path);
  void Write(const TargetRow& row);

 private:
  CsvWriter writer_;
};

// ranges.csv: step,agent_id,range,variance,sensor_x,sensor_y
class RangesCsv {
 public:
  explicit RangesCsv(const std::string& path);
  void Write(const RangeRow& row);

 private:
  CsvWriter writer_;
};

// agent_<id>.csv: step,t,x_est,y_est,p_xx,p_xy,p_yy,pos_x,pos_y,angle,alive,fused,rejected,dropped
class AgentCsv {
 public:
  explicit AgentCsv(const std::string& path);
  void Write(const AgentRow& row);

 private:
  CsvWriter writer_;
};

std::string AgentCsvName(AgentId id);  // "agent_<id>.csv"

}  // namespace deif
