#version 330 core
// facesim's lit fragment shader: pyrender's mesh.frag (MIT licence, pyrender2) reduced to
// what facesim draws: metallic-roughness materials, directional lights, ambient light,
// vertex colours and a base-colour texture. The BRDF is pyrender's (Lambert diffuse,
// GGX distribution, Smith-Schlick occlusion, Schlick Fresnel) term for term, so a frame
// is the same to within one level; without the unused point, spot and shadow paths,
// Mesa's software rasteriser shades it in about half the time (facesim.render).

struct DirectionalLight {
    vec3 color;
    float intensity;
    vec3 direction;
};

struct Material {
    vec3 emissive_factor;
    vec4 base_color_factor;
    float metallic_factor;
    float roughness_factor;
#ifdef HAS_BASE_COLOR_TEX
    sampler2D base_color_texture;
#endif
};

uniform Material material;
uniform DirectionalLight directional_lights[MAX_DIRECTIONAL_LIGHTS];
uniform vec3 cam_pos;
uniform vec3 ambient_light;

in vec3 frag_position;
#ifdef NORMAL_LOC
in vec3 frag_normal;
#endif
#ifdef TEXCOORD_0_LOC
in vec2 uv_0;
#endif
#ifdef COLOR_0_LOC
in vec4 color_multiplier;
#endif

out vec4 frag_color;

const float PI = 3.141592653589793;
const float MIN_ROUGHNESS = 0.04;

vec3 srgb_to_linear(vec3 srgb)
{
    return mix(srgb / 12.92, pow((srgb + 0.055) / 1.055, vec3(2.4)), step(vec3(0.04045), srgb));
}

void main()
{
    vec4 base_color = material.base_color_factor;
#ifdef HAS_BASE_COLOR_TEX
    vec4 texel = texture(material.base_color_texture, uv_0);
    base_color *= vec4(srgb_to_linear(texel.rgb), texel.a);
#endif
    float roughness = clamp(material.roughness_factor, MIN_ROUGHNESS, 1.0);
    float metallic = clamp(material.metallic_factor, 0.0, 1.0);
    float a2 = roughness * roughness * roughness * roughness;  // (perceptual roughness squared) squared
    float k = (roughness + 1.0) * (roughness + 1.0) / 8.0;      // Smith-Schlick
    vec3 c_diff = mix(vec3(0.0), base_color.rgb * (1.0 - MIN_ROUGHNESS), 1.0 - metallic);
    vec3 f0 = mix(vec3(MIN_ROUGHNESS), base_color.rgb, metallic);

    vec3 v = normalize(cam_pos - frag_position);
#ifdef NORMAL_LOC
    vec3 n = normalize(frag_normal);
#else
    vec3 n = v;  // lines have no normals: they face the camera, as in pyrender
#endif
    float nv = clamp(abs(dot(n, v)), 0.001, 1.0);
    float g_v = nv / (nv * (1.0 - k) + k);

    vec3 color = vec3(0.0);
    // DIRECTIONAL_LIGHTS, the scene's count, a constant (facesim.render._lit_shader): a loop
    // of fixed length is unrolled, where pyrender's uniform count cost 3-7 ms a frame at 512²
    for (int i = 0; i < DIRECTIONAL_LIGHTS; i++) {
        vec3 l = normalize(-directional_lights[i].direction);
        vec3 h = normalize(l + v);
        float nl = clamp(dot(n, l), 0.001, 1.0);
        float nh = clamp(dot(n, h), 0.0, 1.0);
        float vh = clamp(dot(v, h), 0.0, 1.0);
        float m = 1.0 - vh;
        vec3 F = f0 + (1.0 - f0) * (m * m * m * m * m);
        float G = g_v * nl / (nl * (1.0 - k) + k);
        float d = nh * nh * (a2 - 1.0) + 1.0;
        float D = a2 / (PI * d * d);
        vec3 radiance = directional_lights[i].intensity * directional_lights[i].color;
        color += nl * radiance * ((1.0 - F) * c_diff / PI + F * G * D / (4.0 * nl * nv + 0.001));
    }
    color += base_color.rgb * ambient_light + material.emissive_factor * material.emissive_factor;
    float alpha = base_color.a;
#ifdef COLOR_0_LOC
    color *= color_multiplier.rgb;
    alpha *= color_multiplier.a;
#endif
    frag_color = clamp(vec4(pow(color, vec3(1.0 / 2.2)), alpha), 0.0, 1.0);
}
