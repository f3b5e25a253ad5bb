// Checks that stay on in release builds (a bare assert vanishes under NDEBUG).
//
//   DEIF_THROW_UNLESS(cond, what): bad input from a caller. Throws std::invalid_argument
//                                  naming the function, the condition and `what`.
//   DEIF_DEMAND(cond):             an internal invariant. Throws std::logic_error; a
//                                  failure is a bug in this code, never in the input.
//
// What throws is documented at each function that uses them (docs/ARCHITECTURE.md,
// "Errors").
#pragma once

#include <stdexcept>
#include <string>

namespace deif::internal {

[[noreturn]] inline void ThrowInvalidArgument(const char* function, const char* condition,
                                              const std::string& what) {
  throw std::invalid_argument(std::string(function) + ": " + what + " (failed: " + condition + ")");
}

[[noreturn]] inline void ThrowLogicError(const char* function, const char* condition,
                                         const char* file, int line) {
  throw std::logic_error(std::string(function) + ": internal invariant failed: " + condition +
                         " (" + file + ":" + std::to_string(line) + ")");
}

}  // namespace deif::internal

#define DEIF_THROW_UNLESS(condition, what)                                          \
  do {                                                                              \
    if (!(condition)) ::deif::internal::ThrowInvalidArgument(__func__, #condition, (what)); \
  } while (false)

#define DEIF_DEMAND(condition)                                                           \
  do {                                                                                   \
    if (!(condition)) ::deif::internal::ThrowLogicError(__func__, #condition, __FILE__, __LINE__); \
  } while (false)
