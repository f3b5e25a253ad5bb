// target.csv / ranges.csv opened in APPEND mode, for a target restarted mid-run. Rows are
// formatted like common/artefacts (FormatDouble) and flushed one by one.
#pragma once

#include <cstdio>
#include <stdexcept>
#include <string>

#include "common/artefacts/artefacts.hpp"

namespace deif::target {

class CsvAppender {
 public:
  // Opens path for appending; writes the header first when the file is new or empty.
  CsvAppender(const std::string& path, const std::string& header) {
    file_ = std::fopen(path.c_str(), "a");
    if (file_ == nullptr) throw std::runtime_error("cannot open " + path + " for appending");
    if (std::ftell(file_) == 0) WriteLine(header);
  }
  ~CsvAppender() {
    if (file_ != nullptr) std::fclose(file_);
  }
  CsvAppender(const CsvAppender&) = delete;
  CsvAppender& operator=(const CsvAppender&) = delete;

  void WriteLine(const std::string& line) {
    std::fputs(line.c_str(), file_);
    std::fputc('\n', file_);
    std::fflush(file_);
  }

 private:
  std::FILE* file_ = nullptr;
};

inline std::string FormatRow(const TargetRow& row) {
  return std::to_string(row.step) + "," + FormatDouble(row.t_s) + "," + FormatDouble(row.p_true.x()) +
         "," + FormatDouble(row.p_true.y());
}

inline std::string FormatRow(const RangeRow& row) {
  return std::to_string(row.step) + "," + std::to_string(row.agent_id) + "," +
         FormatDouble(row.range_m) + "," + FormatDouble(row.variance_m2) + "," +
         FormatDouble(row.p_sensor.x()) + "," + FormatDouble(row.p_sensor.y());
}

inline constexpr const char* kTargetCsvHeader = "step,t,x_true,y_true";
inline constexpr const char* kRangesCsvHeader = "step,agent_id,range,variance,sensor_x,sensor_y";

}  // namespace deif::target
