// Closed-form alignment of point sets and rotation sets, used to compare an
// estimated trajectory with ground truth.
#pragma once

#include <vector>

#include "common/lie.h"

namespace radslam {

/// Umeyama (1991) least-squares alignment: the T_dst_src minimising
/// sum_i ||dst_i - T_dst_src * src_i||^2. With with_scale the result is a
/// similarity (monocular trajectories), otherwise rigid (scale exactly 1).
/// Throws std::invalid_argument on a size mismatch, fewer than 3 points,
/// non-finite coordinates, or (with_scale) point sets that collapse to one point.
/// Collinear input is accepted: the rotation about the line is then arbitrary
/// but the residual is still minimal.
Sim3 alignUmeyama(const std::vector<Vec3>& src, const std::vector<Vec3>& dst, bool with_scale);

/// The rotation R minimising sum_i ||log(R_dst_i^-1 R R_src_i)||^2 (geodesic
/// angles), i.e. R_dst_src for orientations R_src_i = R_src_cam_i: the chordal
/// solution (SVD of sum R_dst_i R_src_i^T) refined by Gauss-Newton on the
/// geodesic error. Throws std::invalid_argument on a size mismatch or empty input.
SO3 alignRotationOnly(const std::vector<SO3>& src, const std::vector<SO3>& dst);

}  // namespace radslam
