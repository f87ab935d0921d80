/* The few GMTL operations libnifalcon's Stamper kinematics uses, so its source compiles without GMTL.
 *
 * Written for this test (not GMTL's code): a 3-vector, a 3x3 matrix (column-major storage, as GMTL's),
 * matrix-vector product, vector arithmetic, dot product, 3x3 inverse, and setTranspose(data) read as
 * GMTL documents it (set this matrix to the transpose of the matrix whose data is given), via a copy so
 * that J.setTranspose(J.getData()) transposes J. <math.h> is included so that libnifalcon's unqualified
 * abs(double) is the floating-point one (with only <stdlib.h> it would be abs(int)).
 */
#ifndef HFAM_TEST_GMTL_SHIM_H
#define HFAM_TEST_GMTL_SHIM_H
#include <math.h>
#include <cmath>

namespace gmtl {

struct Vec3d {
    double v[3];
    Vec3d() : v{0.0, 0.0, 0.0} {}
    Vec3d(double a, double b, double c) : v{a, b, c} {}
    double &operator[](int i) { return v[i]; }
    const double &operator[](int i) const { return v[i]; }
    Vec3d operator+(const Vec3d &o) const { return Vec3d(v[0] + o.v[0], v[1] + o.v[1], v[2] + o.v[2]); }
    Vec3d &operator*=(double s) { v[0] *= s; v[1] *= s; v[2] *= s; return *this; }
    Vec3d &operator/=(double s) { v[0] /= s; v[1] /= s; v[2] /= s; return *this; }
};

inline double dot(const Vec3d &a, const Vec3d &b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

struct Matrix33d {
    enum State { IDENTITY, TRANS, ORTHOGONAL, AFFINE, FULL };
    double m[9]; /* column-major: m[c * 3 + r] */
    Matrix33d() : m{1, 0, 0, 0, 1, 0, 0, 0, 1} {}
    double &operator()(int r, int c) { return m[c * 3 + r]; }
    const double &operator()(int r, int c) const { return m[c * 3 + r]; }
    void setState(State) {}
    const double *getData() const { return m; }
    Matrix33d &setTranspose(const double *data) {
        double t[9];
        for (int k = 0; k < 9; ++k) t[k] = data[k];
        for (int r = 0; r < 3; ++r)
            for (int c = 0; c < 3; ++c) (*this)(r, c) = t[r * 3 + c];
        return *this;
    }
    Vec3d operator*(const Vec3d &x) const {
        Vec3d y;
        for (int r = 0; r < 3; ++r) y[r] = (*this)(r, 0) * x[0] + (*this)(r, 1) * x[1] + (*this)(r, 2) * x[2];
        return y;
    }
};

inline Matrix33d &invert(Matrix33d &a) {
    const Matrix33d s = a;
    double det = s(0, 0) * (s(1, 1) * s(2, 2) - s(1, 2) * s(2, 1)) - s(0, 1) * (s(1, 0) * s(2, 2) - s(1, 2) * s(2, 0)) +
                 s(0, 2) * (s(1, 0) * s(2, 1) - s(1, 1) * s(2, 0));
    a(0, 0) = (s(1, 1) * s(2, 2) - s(1, 2) * s(2, 1)) / det;
    a(0, 1) = (s(0, 2) * s(2, 1) - s(0, 1) * s(2, 2)) / det;
    a(0, 2) = (s(0, 1) * s(1, 2) - s(0, 2) * s(1, 1)) / det;
    a(1, 0) = (s(1, 2) * s(2, 0) - s(1, 0) * s(2, 2)) / det;
    a(1, 1) = (s(0, 0) * s(2, 2) - s(0, 2) * s(2, 0)) / det;
    a(1, 2) = (s(0, 2) * s(1, 0) - s(0, 0) * s(1, 2)) / det;
    a(2, 0) = (s(1, 0) * s(2, 1) - s(1, 1) * s(2, 0)) / det;
    a(2, 1) = (s(0, 1) * s(2, 0) - s(0, 0) * s(2, 1)) / det;
    a(2, 2) = (s(0, 0) * s(1, 1) - s(0, 1) * s(1, 0)) / det;
    return a;
}

} // namespace gmtl
#endif
