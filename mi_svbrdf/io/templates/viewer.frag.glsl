#version 300 es
precision highp float;
precision highp int;
uniform highp sampler2D uNormal, uDiffuse, uRoughness, uSpecular;  // 8-bit codes / 255, fetched per texel
uniform vec3 uLight;      // point light position
uniform vec3 uView;       // camera position (direction to the viewer per texel)
uniform vec3 uIntensity;  // I * 2^exposure
uniform int uShow;        // 0 render, 1 normal, 2 diffuse, 3 roughness, 4 specular
uniform int uDistribution;  // the material's model: 0 GGX, 1 Beckmann
out vec4 outColor;
const float PI = 3.14159265358979;
const float EPS = 1e-3;   // every denominator's floor

vec3 srgbDecode(vec3 v) {  // IEC 61966-2-1, as colour-science's cctf_decoding
  return mix(pow((v + 0.055) / 1.055, vec3(2.4)), v / 12.92, vec3(lessThanEqual(v, vec3(0.04045))));
}
vec3 unit(vec3 v) { return v * inversesqrt(max(dot(v, v), 1e-12)); }

void main() {
  ivec2 size = textureSize(uRoughness, 0);
  int j = int(gl_FragCoord.x);
  int i = size.y - 1 - int(gl_FragCoord.y);  // canvas row i = texel row i (top row first)
  ivec2 t = ivec2(j, i);
  vec3 nCode = texelFetch(uNormal, t, 0).rgb;
  vec3 dCode = texelFetch(uDiffuse, t, 0).rgb;
  float rCode = texelFetch(uRoughness, t, 0).r;
  vec3 sCode = texelFetch(uSpecular, t, 0).rgb;
  if (uShow == 1) { outColor = vec4(nCode, 1.0); return; }
  if (uShow == 2) { outColor = vec4(dCode, 1.0); return; }
  if (uShow == 3) { outColor = vec4(vec3(rCode), 1.0); return; }
  if (uShow == 4) { outColor = vec4(sCode, 1.0); return; }

  vec3 n = nCode * 2.0 - 1.0;
  float len = length(n);
  n = len > 1e-6 ? n / len : vec3(0.0, 0.0, 1.0);
  n = unit(n);
  vec3 d = srgbDecode(dCode);
  vec3 s = srgbDecode(sCode);
  float r = clamp(rCode, 1e-3, 1.0);
  // texel centre on the [-1, 1]^2 plane, +y up
  vec3 p = vec3(-1.0 + (2.0 * float(j) + 1.0) / float(size.x), 1.0 - (2.0 * float(i) + 1.0) / float(size.y), 0.0);
  vec3 toLight = uLight - p;
  vec3 wl = unit(toLight);
  vec3 wv = unit(uView - p);
  vec3 h = unit(wl + wv);
  float nh = max(dot(n, h), 0.0), nl = max(dot(n, wl), 0.0), nv = max(dot(n, wv), 0.0), vh = max(dot(wv, h), 0.0);
  float alpha = r * r;
  float a2 = alpha * alpha;
  float D, k;                                                         // D and Smith-Schlick's k
  vec3 nxh = cross(n, h);
  float s2 = nh > 1e-3 ? dot(nxh, nxh) : 1.0 - nh * nh;             // sin^2(theta_h) without 1 - c^2's cancellation
  if (uDistribution == 1) {                                           // Beckmann
    float c2 = max(nh, EPS) * max(nh, EPS);
    D = exp(-s2 / (a2 * c2)) / (PI * a2 * c2 * c2);
    k = alpha * sqrt(2.0 / PI);
  } else {                                                            // GGX
    float base = max(s2 + a2 * nh * nh, EPS);
    D = a2 / (PI * base * base);
    k = alpha / 2.0;
  }
  float G = 1.0 / max(nl * (1.0 - k) + k, EPS) / max(nv * (1.0 - k) + k, EPS);
  vec3 F = s + (1.0 - s) * exp2((-5.55473 * vh - 6.98316) * vh);     // the authors' Fresnel
  vec3 f = F * G * D / 4.0 + d * (1.0 - s) / PI;
  vec3 radiance = f * PI * uIntensity * nl / max(dot(toLight, toLight), 1e-12);
  outColor = vec4(pow(clamp(radiance, 0.0, 1.0), vec3(1.0 / 2.2)), 1.0);  // core.metrics.display
}
