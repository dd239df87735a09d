// How lights light a surface point (resolve) and what a textured dome shows behind everything (background). Every
// light is analytic, with no shadowing yet:
// - distant: Lambert diffuse plus a GGX lobe from one direction, `radiance` being the irradiance it delivers;
// - sphere: exact irradiance of a uniform sphere, horizon included (Snyder's formula, as Frostbite's "Moving to
//   PBR" writes it); specular from the representative point (the sphere's point nearest the reflected ray) with the
//   lobe widened by the sphere's angular size and renormalized (Karis, "Real Shading in Unreal Engine 4", 2013);
// - rect: exact irradiance of the rectangle clipped to the surface's horizon (Lambert's polygon formula); only its
//   front (the side its -Z faces) emits; specular from the representative point where the reflected ray meets its
//   plane (clamped into it), widened and renormalized as a sphere of the same area would be;
// - dome: uniform radiance, or a lat-long texture: diffuse from its irradiance as 9 spherical harmonics coefficients
//   (frame.environment, integrated on the CPU), specular from the same irradiance in the reflected direction
//   (a very rough blurred environment) times the lobe's directional albedo; the occlusion input scales both.
// Include after frame.h (and texture.h, for the dome's background).
#ifndef TESSERA_LIGHTS_H
#define TESSERA_LIGHTS_H

const float PI = 3.14159265358979;

// The GGX microfacet lobe (alpha = roughness^2, Smith-Schlick shadowing, Schlick Fresnel) times the cosine, for light
// of unit irradiance arriving from `toLight`; nothing for a material without reflectance (diffuse only). Written with
// the unnormalized half vector s = l + v, whose length is 2 (v.h) and with which n.h = n.s / |s|, and with n.v
// cancelled between G and 1 / (4 n.v): one square root and one division, where the textbook form takes a normalize
// and four divisions (on a CPU device each is a slow vector instruction per pixel: resolve 2-4 % cheaper, session 31).
vec3 specular_lobe(vec3 n, vec3 toEye, vec3 toLight, vec3 f0, float alpha) {
    float nl = dot(n, toLight);
    if (nl <= 0.0 || max(f0.r, max(f0.g, f0.b)) <= 0.0) return vec3(0.0);
    float nv = max(dot(n, toEye), 1e-4);
    vec3 s = toLight + toEye;
    float ss = dot(s, s);  // 4 (v.h)^2, as |l + v|^2 = 2 + 2 l.v
    if (!(ss > 0.0)) return vec3(0.0);  // light from exactly behind the eye's ray: no half vector
    float vh = 0.5 * sqrt(ss);
    float ns = max(dot(n, s), 0.0);
    float a2 = alpha * alpha, k = alpha / 2.0;
    // D = a2 / (pi q^2) with q = (n.h)^2 (a2 - 1) + 1 = (ns^2 (a2 - 1) + ss) / ss; G / (4 n.v) = nl / (4 (nl (1 - k) + k) (nv (1 - k) + k)).
    float q = ns * ns * (a2 - 1.0) + ss;
    float lobe = a2 * nl * ss * ss / (4.0 * PI * q * q * (nl * (1.0 - k) + k) * (nv * (1.0 - k) + k));
    float m = 1.0 - vh, m2 = m * m;
    return lobe * (f0 + (1.0 - f0) * (m2 * m2 * m));
}

float lobe_alpha(float roughness) { return max(roughness * roughness, 1e-3); }

// Light reflected towards `toEye` from a distant light arriving from `toLight` with unit irradiance: Lambert diffuse
// plus the GGX lobe, times the cosine.
vec3 direct_light(vec3 n, vec3 toEye, vec3 toLight, vec3 albedo, vec3 f0, float roughness) {
    float nl = dot(n, toLight);
    if (nl <= 0.0) return vec3(0.0);
    return albedo / PI * nl + specular_lobe(n, toEye, toLight, f0, lobe_alpha(roughness));
}

// What fraction of a uniform environment the specular lobe reflects (directional albedo), by the analytic fit of
// the split-sum integral that Karis published for mobile (Unreal Engine 4, 2014).
vec3 environment_reflectance(vec3 f0, float roughness, float nv) {
    vec4 r = roughness * vec4(-1.0, -0.0275, -0.572, 0.022) + vec4(1.0, 0.0425, 1.04, -0.04);
    float a004 = min(r.x * r.x, exp2(-9.28 * nv)) * r.x + r.y;
    vec2 ab = vec2(-1.04, 1.04) * a004 + r.zw;
    return max(f0.r, max(f0.g, f0.b)) <= 0.0 ? vec3(0.0) : f0 * ab.x + ab.y;  // no reflectance, no lobe (diffuse only)
}

// Integral of the cosine to `n` over a sphere seen at angle acos(cosTheta) from n, whose angular radius sigma has
// sin^2 = sinSigma2: pi sin^2(sigma) cos(theta) while wholly above the horizon, the exact partial form across it.
float sphere_irradiance(float cosTheta, float sinSigma2) {
    if (cosTheta * cosTheta > sinSigma2) return PI * sinSigma2 * max(cosTheta, 0.0);
    float sinTheta = sqrt(max(1.0 - cosTheta * cosTheta, 1e-8));
    float x = sqrt(max(1.0 / sinSigma2 - 1.0, 1e-8));  // cot(sigma)
    float y = clamp(-x * cosTheta / sinTheta, -1.0, 1.0);
    float sinThetaSqrtY = sinTheta * sqrt(max(1.0 - y * y, 0.0));
    return max((cosTheta * acos(y) - x * sinThetaSqrtY) * sinSigma2 + atan(sinThetaSqrtY / x), 0.0);
}

// Integral of the cosine to `n` over the solid angle of the quad q0 q1 q2 q3 (corners relative to the point), clipped
// to the hemisphere around n: Lambert's formula, half the sum over the edges of the angle each spans times the
// cosine of its plane's normal with n.
float quad_irradiance(vec3 q0, vec3 q1, vec3 q2, vec3 q3, vec3 n) {
    vec3 corners[4] = vec3[4](q0, q1, q2, q3);
    vec3 clipped[5];
    int count = 0;
    for (int i = 0; i < 4; ++i) {
        vec3 a = corners[i], b = corners[(i + 1) & 3];
        float da = dot(a, n), db = dot(b, n);
        if (da >= 0.0) clipped[count++] = a;
        if ((da >= 0.0) != (db >= 0.0)) clipped[count++] = a + (b - a) * (da / (da - db));
    }
    float sum = 0.0;
    for (int i = 0; i < count; ++i) {
        vec3 a = normalize(clipped[i]), b = normalize(clipped[i + 1 == count ? 0 : i + 1]);
        vec3 axis = cross(a, b);
        float len = length(axis);
        if (len > 1e-7) sum += acos(clamp(dot(a, b), -1.0, 1.0)) * dot(axis, n) / len;
    }
    return 0.5 * abs(sum);
}

// The textured dome's diffuse radiance per unit albedo for a direction in its own frame: sum c_i Y_i(d).
vec3 environment_irradiance(GpuFrame frame, vec3 d) {
    return frame.environment[0].rgb * 0.282095 +
           0.488603 * (frame.environment[1].rgb * d.y + frame.environment[2].rgb * d.z + frame.environment[3].rgb * d.x) +
           1.092548 * (frame.environment[4].rgb * d.x * d.y + frame.environment[5].rgb * d.y * d.z + frame.environment[7].rgb * d.x * d.z) +
           0.315392 * frame.environment[6].rgb * (3.0 * d.z * d.z - 1.0) + 0.546274 * frame.environment[8].rgb * (d.x * d.x - d.y * d.y);
}

// A world direction in a dome's frame (its X, Y and Z = X x Y axes).
vec3 dome_direction(GpuLight light, vec3 world) {
    vec3 z = cross(light.axisX.xyz, light.axisY.xyz);
    return vec3(dot(world, light.axisX.xyz), dot(world, light.axisY.xyz), dot(world, z));
}

// Light a distant light sends towards the eye from a surface point of normal n.
vec3 distant_light_contribution(GpuLight light, vec3 n, vec3 toEye, vec3 albedo, vec3 f0, float roughness) {
    return light.radiance.rgb * direct_light(n, toEye, -light.directionType.xyz, albedo, f0, roughness);
}

// Light any other light (dome, sphere, rect) sends towards the eye from the surface point `p` (camera-relative),
// normal n. Apart from the distant lights' (which the frame lists first: TS_SPEC_LIGHT_COUNTS), so that a loop over one
// kind runs only its code: lavapipe runs every branch of a shader, masked. `areaLights` (a specialization constant in
// resolve) false: the frame has only distant lights and untextured domes, and none of the other code is compiled in.
vec3 other_light_contribution(GpuFrame frame, GpuLight light, vec3 p, vec3 n, vec3 toEye, vec3 albedo, vec3 f0, float roughness, float occlusion,
                              bool areaLights) {
    uint type = uint(light.directionType.w);
    vec3 radiance = light.radiance.rgb;
    float nv = max(dot(n, toEye), 0.0);
    if (!areaLights || (type == TS_LIGHT_DOME && light.texture == TS_NO_TEXTURE))  // a uniform dome; occlusion scales it
        return radiance * occlusion * (albedo + environment_reflectance(f0, roughness, nv));
    if (type == TS_LIGHT_DOME) {
        vec3 reflected = reflect(-toEye, n);
        return radiance * occlusion * (albedo * environment_irradiance(frame, dome_direction(light, n)) +
                                       environment_reflectance(f0, roughness, nv) * environment_irradiance(frame, dome_direction(light, reflected)));
    }
    float alpha = lobe_alpha(roughness);
    vec3 reflected = reflect(-toEye, n);
    vec3 toCenter = light.position.xyz - p;
    if (type == TS_LIGHT_SPHERE) {
        float radius = light.position.w;
        float distance2 = max(dot(toCenter, toCenter), 1e-12), distance = sqrt(distance2);
        float sinSigma2 = min(radius * radius / distance2, 0.9999);  // within the sphere: nearly the whole hemisphere
        vec3 color = albedo / PI * radiance * sphere_irradiance(dot(n, toCenter / distance), sinSigma2);
        vec3 centerToRay = dot(toCenter, reflected) * reflected - toCenter;
        vec3 nearest = toCenter + centerToRay * clamp(radius / max(length(centerToRay), 1e-12), 0.0, 1.0);
        float widened = min(alpha + radius / (2.0 * distance), 1.0);
        return color + radiance * (PI * sinSigma2) * (alpha / widened) * (alpha / widened) * specular_lobe(n, toEye, normalize(nearest), f0, alpha);
    }
    // TS_LIGHT_RECT: its front faces directionType.xyz; nothing reaches points behind it.
    vec3 front = light.directionType.xyz;
    if (dot(toCenter, front) >= 0.0) return vec3(0.0);
    vec3 ax = light.axisX.xyz, ay = light.axisY.xyz;
    vec3 color = albedo / PI * radiance * quad_irradiance(toCenter - ax - ay, toCenter + ax - ay, toCenter + ax + ay, toCenter - ax + ay, n);
    // The representative point: where the reflected ray meets the plane (else the point along it as far as the
    // centre), clamped into the rectangle.
    float along = dot(reflected, front);
    float t = along < -1e-6 ? dot(toCenter, front) / along : length(toCenter);
    vec3 offset = reflected * t - toCenter;
    vec2 extent = vec2(dot(ax, ax), dot(ay, ay));
    vec2 st = clamp(vec2(dot(offset, ax), dot(offset, ay)) / max(extent, vec2(1e-12)), -1.0, 1.0);
    vec3 point = toCenter + st.x * ax + st.y * ay;
    float distance2 = max(dot(point, point), 1e-12), distance = sqrt(distance2);
    float area = 4.0 * length(cross(ax, ay));
    float solidAngle = min(area * abs(dot(point / distance, front)) / distance2, 2.0 * PI);
    float widened = min(alpha + sqrt(area / PI) / (2.0 * distance), 1.0);
    return color + radiance * solidAngle * (alpha / widened) * (alpha / widened) * specular_lobe(n, toEye, point / distance, f0, alpha);
}

#endif
