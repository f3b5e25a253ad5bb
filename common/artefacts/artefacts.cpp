// The run artefacts of DESIGN.md ("Run artefacts"): one CSV row per step, flushed at once.
#include "common/artefacts/artefacts.hpp"

#include <cerrno>
#include <cstring>
#include <stdexcept>
#include <utility>

namespace deif {

CsvWriter::CsvWriter(const std::string& path, const std::string& header) : path_(path) {
  file_ = std::fopen(path.c_str(), "w");
  if (file_ == nullptr) {
    throw std::runtime_error("cannot open '" + path + "' for writing: " + std::strerror(errno));
  }
  WriteLine(header);
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

const char* const kTargetHeader = "step,t,x_true,y_true";
const char* const kRangesHeader = "step,agent_id,range,variance,sensor_x,sensor_y";
const char* const kAgentHeader =
    "step,t,x_est,y_est,p_xx,p_xy,p_yy,pos_x,pos_y,angle,alive,fused,rejected,dropped";

}  // namespace

TargetCsv::TargetCsv(const std::string& path) : writer_(path, kTargetHeader) {}

void TargetCsv::Write(const TargetRow& row) {
  writer_.WriteLine(std::to_string(row.step) + "," + FormatDouble(row.t_s) + "," +
                    FormatDouble(row.p_true.x()) + "," + FormatDouble(row.p_true.y()));
}

RangesCsv::RangesCsv(const std::string& path) : writer_(path, kRangesHeader) {}

void RangesCsv::Write(const RangeRow& row) {
  writer_.WriteLine(std::to_string(row.step) + "," + std::to_string(row.agent_id) + "," +
                    FormatDouble(row.range_m) + "," + FormatDouble(row.variance_m2) + "," +
                    FormatDouble(row.p_sensor.x()) + "," + FormatDouble(row.p_sensor.y()));
}

AgentCsv::AgentCsv(const std::string& path) : writer_(path, kAgentHeader) {}

void AgentCsv::Write(const AgentRow& row) {
  writer_.WriteLine(
      std::to_string(row.step) + "," + FormatDouble(row.t_s) + "," +
      FormatDouble(row.estimate_m.x()) + "," + FormatDouble(row.estimate_m.y()) + "," +
      FormatDouble(row.covariance(0, 0)) + "," + FormatDouble(row.covariance(0, 1)) + "," +
      FormatDouble(row.covariance(1, 1)) + "," + FormatDouble(row.position_m.x()) + "," +
      FormatDouble(row.position_m.y()) + "," + FormatDouble(row.angle_rad) + "," +
      std::to_string(row.alive) + "," + std::to_string(row.fused) + "," +
      std::to_string(row.rejected) + "," + std::to_string(row.dropped));
}

std::string AgentCsvName(AgentId id) { return "agent_" + std::to_string(id) + ".csv"; }

}  // namespace deif
