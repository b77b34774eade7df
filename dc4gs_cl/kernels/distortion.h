// distortion.h: the lens models of -D DISTORTION (1 RADIAL_TANGENTIAL, 2 FISHEYE; dc4gs_cl/scene/distortion.py
// states them and holds their float64 twins): the distorted normalised point D(u) of u = (x/z, y/z), its
// Jacobian dD/du (symmetric: (j00, j01, j11)) and that Jacobian's derivatives in u_x and u_y (the backward's).
// Camera fields: dist = k1..k6 (FISHEYE: k1..k4, 0, 0), p1, p2; lim, r2_max (the clamp box and the culling radius
// in u, set by the host).

#ifndef DC4GS_DISTORTION_H
#define DC4GS_DISTORTION_H

// rho(s), rho'(s), rho''(s) of the radial factor, s = |u|^2.
inline float3 radial_profile(const Camera *cam, float s) {
    const float *k = cam->dist;
#if DISTORTION == 1
    float num = 1.f + s * (k[0] + s * (k[1] + s * k[2])), dnum = k[0] + s * (2.f * k[1] + 3.f * s * k[2]);
    float d2num = 2.f * k[1] + 6.f * s * k[2];
    float den = 1.f + s * (k[3] + s * (k[4] + s * k[5])), dden = k[3] + s * (2.f * k[4] + 3.f * s * k[5]);
    float d2den = 2.f * k[4] + 6.f * s * k[5];
    float rden = 1.f / den, rho = num * rden, drho = (dnum - rho * dden) * rden;
    return (float3)(rho, drho, (d2num - 2.f * drho * dden - rho * d2den) * rden);
#elif DISTORTION == 2
    if (s < FISHEYE_SERIES_R2) {   // 1 + a1 s + a2 s^2 + a3 s^3 (distortion.fisheye_series): the closed form cancels
        float a1 = k[0] - 1.f / 3.f, a2 = k[1] - k[0] + 1.f / 5.f;
        float a3 = 14.f / 15.f * k[0] - 5.f / 3.f * k[1] + k[2] - 1.f / 7.f;
        return (float3)(1.f + s * (a1 + s * (a2 + s * a3)), a1 + s * (2.f * a2 + 3.f * s * a3), 2.f * a2 + 6.f * s * a3);
    }
    float r = sqrt_nocall(s), th = atan(r), t2 = th * th;
    float F = th * (1.f + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3]))));
    float dF = 1.f + t2 * (3.f * k[0] + t2 * (5.f * k[1] + t2 * (7.f * k[2] + t2 * 9.f * k[3])));
    float d2F = th * (6.f * k[0] + t2 * (20.f * k[1] + t2 * (42.f * k[2] + t2 * 72.f * k[3])));
    float dth = 1.f / (1.f + s), d2th = -2.f * r * dth * dth;
    float drd = dF * dth, d2rd = d2F * dth * dth + dF * d2th, rr = 1.f / r;   // the distorted radius' derivatives
    float rho = F * rr, rho_r = (drd - rho) * rr, rho_rr = (d2rd - 2.f * rho_r) * rr;
    return (float3)(rho, 0.5f * rho_r * rr, 0.25f * (rho_rr - rho_r * rr) * rr * rr);
#endif
}

inline float2 distort(const Camera *cam, float2 u) {
    float s = u.x * u.x + u.y * u.y, rho = radial_profile(cam, s).x, p1 = cam->dist[6], p2 = cam->dist[7];
    return (float2)(u.x * rho + 2.f * p1 * u.x * u.y + p2 * (s + 2.f * u.x * u.x),
                    u.y * rho + p1 * (s + 2.f * u.y * u.y) + 2.f * p2 * u.x * u.y);
}

// dD/du as (j00, j01, j11); with hx, hy non-null also d(j00, j01, j11)/du_x and /du_y.
inline float3 distort_jacobian(const Camera *cam, float2 u, float3 *hx, float3 *hy) {
    float x = u.x, y = u.y, p1 = cam->dist[6], p2 = cam->dist[7];
    float3 prof = radial_profile(cam, x * x + y * y);
    float d1 = prof.y, d2 = prof.z;
    if (hx) {
        float cross = 2.f * y * d1 + 4.f * x * x * y * d2 + 2.f * p1, other = 2.f * x * d1 + 4.f * x * y * y * d2 + 2.f * p2;
        *hx = (float3)(6.f * x * d1 + 4.f * x * x * x * d2 + 6.f * p2, cross, other);
        *hy = (float3)(cross, other, 6.f * y * d1 + 4.f * y * y * y * d2 + 6.f * p1);
    }
    return (float3)(prof.x + 2.f * x * x * d1 + 2.f * p1 * y + 6.f * p2 * x, 2.f * x * y * d1 + 2.f * p1 * x + 2.f * p2 * y,
                    prof.x + 2.f * y * y * d1 + 6.f * p1 * y + 2.f * p2 * x);
}

#endif
