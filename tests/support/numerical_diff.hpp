// Central-difference derivatives, the reference every analytic Jacobian is checked against.
#pragma once

#include "common/core/types.hpp"

namespace deif::test {

// df/dx ~ (f(x + h) - f(x - h)) / (2 h); truncation error O(h^2 f''').
template <typename ScalarFunction>
double CentralDerivative(const ScalarFunction& f, double x, double h = 1e-6) {
  return (f(x + h) - f(x - h)) / (2.0 * h);
}

// The 1x2 gradient of a scalar function of a point in the plane, one axis at a time.
template <typename PlaneFunction>
RowVector2 CentralGradient(const PlaneFunction& f, const Vector2& x, double h = 1e-6) {
  RowVector2 gradient;
  for (int axis = 0; axis < 2; ++axis) {
    Vector2 step = Vector2::Zero();
    step(axis) = h;
    gradient(axis) = (f(x + step) - f(x - step)) / (2.0 * h);
  }
  return gradient;
}

}  // namespace deif::test
