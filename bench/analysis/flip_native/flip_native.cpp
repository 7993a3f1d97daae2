// gibench's C interface to NVIDIA's FLIP.h (HDR-FLIP), loaded with ctypes by bench/analysis/flip_native/__init__.py.
//
// flip_hdr: FLIP::evaluate in HDR mode, what the pip wheel flip-evaluator computes (kept for the tests).
// flip_reference_features + flip_against_reference: the same map in two halves. FLIP's LDR pass
// filters the reference and the test image independently and only then combines them pixel by
// pixel, so the reference's half (its tone-mapped, spatially filtered CIELab-Hunt colour and its
// edge and point responses, per exposure) is computed once per reference and reused for every
// image judged against it. Each half repeats FLIP.h's float operations in FLIP.h's order
// (FLIP::image::computeColorDifference and computeFeatureDifferenceAndFinalError, split by image),
// so the map is bit for bit that of flip_hdr; the tests check it.
#include "FLIP.h"
#include <omp.h>

namespace
{
    using FLIP::color3;

    // Per pixel and exposure, what FLIP's combine step reads of one image.
    struct Features
    {
        float L, a, b;        // spatially filtered colour, CIELab with the Hunt adjustment
        float edge, point;    // feature (edge and point) detector responses
    };

    // FLIP's filter weights (FLIP::image::setSpatialFilters, setFeatureFilter), one array per channel.
    struct Filters
    {
        int spatialRadius = 0, featureRadius = 0;
        std::vector<float> Y, Cx, Cz1, Cz2, gauss, d1, d2;

        explicit Filters(float ppd)
        {
            spatialRadius = FLIP::calculateSpatialFilterRadius(ppd);
            const float stdDev = 0.5f * FLIP::FLIPConstants.gw * ppd;
            featureRadius = int(std::ceil(3.0f * stdDev));
            FLIP::image<color3> spatialYCx(2 * spatialRadius + 1, 1), spatialCz(2 * spatialRadius + 1, 1);
            FLIP::image<color3> feature(2 * featureRadius + 1, 1);
            FLIP::image<color3>::setSpatialFilters(spatialYCx, spatialCz, ppd, spatialRadius);
            FLIP::image<color3>::setFeatureFilter(feature, ppd);
            for (int i = 0; i < 2 * spatialRadius + 1; i++)
            {
                Y.push_back(spatialYCx.get(i, 0).x);
                Cx.push_back(spatialYCx.get(i, 0).y);
                Cz1.push_back(spatialCz.get(i, 0).x);
                Cz2.push_back(spatialCz.get(i, 0).y);
            }
            for (int i = 0; i < 2 * featureRadius + 1; i++)
            {
                gauss.push_back(feature.get(i, 0).x);
                d1.push_back(feature.get(i, 0).y);
                d2.push_back(feature.get(i, 0).z);
            }
        }
    };

    // acc[x] += weights[k] * row[clamp(x + k - radius)] for k = 0..2 radius, in that order for each x
    // (FLIP's horizontal pass, whose sums run over the taps left to right): `padded` holds the row
    // with its edge pixels repeated radius times on each side, so the loop over x is branch-free.
    inline void horizontal(const float* __restrict padded, const float* __restrict weights, int radius, int w,
                           float* __restrict acc)
    {
        for (int x = 0; x < w; x++)
        {
            acc[x] = 0.0f;
        }
        for (int k = 0; k <= 2 * radius; k++)
        {
            const float wk = weights[k];
            const float* __restrict src = padded + k;
            for (int x = 0; x < w; x++)
            {
                acc[x] += wk * src[x];
            }
        }
    }

    inline void pad(const float* __restrict row, int w, int radius, float* __restrict padded)
    {
        for (int j = 0; j < w + 2 * radius; j++)
        {
            padded[j] = row[Min(Max(0, j - radius), w - 1)];
        }
    }

    // acc[x] += weights[k] * plane[clamp(y + k - radius)][x] for k = 0..2 radius (FLIP's vertical pass).
    inline void vertical(const float* __restrict plane, const float* __restrict weights, int radius, int w, int h, int y,
                         float* __restrict acc)
    {
        for (int x = 0; x < w; x++)
        {
            acc[x] = 0.0f;
        }
        for (int k = 0; k <= 2 * radius; k++)
        {
            const float wk = weights[k];
            const float* __restrict src = plane + size_t(Min(Max(0, y + k - radius), h - 1)) * w;
            for (int x = 0; x < w; x++)
            {
                acc[x] += wk * src[x];
            }
        }
    }

    // FLIP's error at a pixel from the two images' features (the ends of FLIP::image::computeColorDifference
    // and computeFeatureDifferenceAndFinalError, same operations).
    inline float combine(const Features& r, const Features& t, float cmax, float pccmax)
    {
        color3 reference(r.L, r.a, r.b), test(t.L, t.a, t.b);
        float colorDifference = color3::HyAB(reference, test);
        colorDifference = powf(colorDifference, FLIP::FLIPConstants.gqc);
        if (colorDifference < pccmax)
        {
            colorDifference *= FLIP::FLIPConstants.gpt / pccmax;
        }
        else
        {
            colorDifference = FLIP::FLIPConstants.gpt + ((colorDifference - pccmax) / (cmax - pccmax)) * (1.0f - FLIP::FLIPConstants.gpt);
        }
        const float normalizationFactor = 1.0f / std::sqrt(2.0f);
        const float edgeDifference = std::abs(r.edge - t.edge);
        const float pointDifference = std::abs(r.point - t.point);
        const float featureDifference = std::pow(normalizationFactor * Max(edgeDifference, pointDifference), FLIP::FLIPConstants.gqf);
        return std::pow(colorDifference, 1.0f - featureDifference);
    }

    // One image's half of HDR-FLIP at one exposure, as planes (one float per pixel and channel).
    // With `reference` set, each pixel's error against it is folded into `errorMap` (the maximum
    // over exposures, FLIP::image::setMaxExposure); otherwise the features are written to `out`.
    class Half
    {
        const Filters filters;
        const int w, h;
        std::vector<float> Y, Cx, Cz, yNormalized;              // the exposed, tone-mapped image in YCxCz
        std::vector<float> hY, hCx, hCz1, hCz2, hDx, hDdx, hGauss;  // horizontal passes

    public:
        Half(int width, int height, float ppd)
            : filters(ppd), w(width), h(height)
        {
            for (auto* plane : { &Y, &Cx, &Cz, &yNormalized, &hY, &hCx, &hCz1, &hCz2, &hDx, &hDdx, &hGauss })
            {
                plane->resize(size_t(w) * h);
            }
        }

        void compute(const float* linear, float exposure, Features* out, const Features* reference, int referenceWidth,
                     int x0, int y0, float* errorMap, int threads)
        {
            const float m = std::pow(2.0f, exposure);    // FLIP::image::expose
            const float* tc = FLIP::ToneMappingCoefficients[1];   // ACES
            const float oneOver116 = 1.0f / 116.0f;
            const float sixteenOver116 = 16.0f / 116.0f;
            const float cmax = color3::computeMaxDistance(FLIP::FLIPConstants.gqc);
            const float pccmax = FLIP::FLIPConstants.gpc * cmax;
            const int rs = filters.spatialRadius, rf = filters.featureRadius;
#pragma omp parallel num_threads(threads > 0 ? threads : omp_get_max_threads())
            {
                std::vector<float> padded(size_t(w) + 2 * size_t(Max(rs, rf)));
                std::vector<float> a0(w), a1(w), a2(w), a3(w);
#pragma omp for
                for (int i = 0; i < w * h; i++)
                {
                    // expose, toneMap, clamp, LinearRGBToYCxCz: FLIP::tensor's per-pixel steps
                    color3 color = color3(linear + 3 * size_t(i)) * m;
                    color = color3(((color * color) * tc[0] + color * tc[1] + tc[2]) / (color * color * tc[3] + color * tc[4] + tc[5]));
                    color = color3::clamp(color, 0.0f, 1.0f);
                    color = color3::XYZToYCxCz(color3::LinearRGBToXYZ(color));
                    Y[i] = color.x;
                    Cx[i] = color.y;
                    Cz[i] = color.z;
                    yNormalized[i] = color.x * oneOver116 + sixteenOver116;
                }
#pragma omp for
                for (int y = 0; y < h; y++)
                {
                    const size_t row = size_t(y) * w;
                    pad(&Y[row], w, rs, padded.data());
                    horizontal(padded.data(), filters.Y.data(), rs, w, &hY[row]);
                    pad(&Cx[row], w, rs, padded.data());
                    horizontal(padded.data(), filters.Cx.data(), rs, w, &hCx[row]);
                    pad(&Cz[row], w, rs, padded.data());
                    horizontal(padded.data(), filters.Cz1.data(), rs, w, &hCz1[row]);
                    horizontal(padded.data(), filters.Cz2.data(), rs, w, &hCz2[row]);
                    pad(&yNormalized[row], w, rf, padded.data());
                    horizontal(padded.data(), filters.d1.data(), rf, w, &hDx[row]);
                    horizontal(padded.data(), filters.d2.data(), rf, w, &hDdx[row]);
                    horizontal(padded.data(), filters.gauss.data(), rf, w, &hGauss[row]);
                }
                std::vector<Features> features(w);
                std::vector<float> a4(w), a5(w);
#pragma omp for
                for (int y = 0; y < h; y++)
                {
                    vertical(hY.data(), filters.Y.data(), rs, w, h, y, a0.data());
                    vertical(hCx.data(), filters.Cx.data(), rs, w, h, y, a1.data());
                    vertical(hCz1.data(), filters.Cz1.data(), rs, w, h, y, a2.data());
                    vertical(hCz2.data(), filters.Cz2.data(), rs, w, h, y, a3.data());
                    for (int x = 0; x < w; x++)
                    {
                        color3 filtered = color3(a0[x], a1[x], a2[x] + a3[x]);
                        filtered = color3::clamp(color3::XYZToLinearRGB(color3::YCxCzToXYZ(filtered)));
                        filtered = color3::XYZToCIELab(color3::LinearRGBToXYZ(filtered));
                        features[x].L = filtered.x;
                        features[x].a = color3::Hunt(filtered.x, filtered.y);
                        features[x].b = color3::Hunt(filtered.x, filtered.z);
                    }
                    vertical(hDx.data(), filters.gauss.data(), rf, w, h, y, a0.data());     // dx
                    vertical(hDdx.data(), filters.gauss.data(), rf, w, h, y, a1.data());    // ddx
                    vertical(hGauss.data(), filters.d1.data(), rf, w, h, y, a2.data());     // dy
                    vertical(hGauss.data(), filters.d2.data(), rf, w, h, y, a3.data());     // ddy
                    for (int x = 0; x < w; x++)
                    {
                        features[x].edge = std::sqrt(a0[x] * a0[x] + a2[x] * a2[x]);
                        features[x].point = std::sqrt(a1[x] * a1[x] + a3[x] * a3[x]);
                    }
                    if (reference == nullptr)
                    {
                        std::copy(features.begin(), features.end(), out + size_t(y) * w);
                        continue;
                    }
                    const Features* referenceRow = reference + size_t(y + y0) * referenceWidth + x0;
                    float* errorRow = errorMap + size_t(y) * w;
                    for (int x = 0; x < w; x++)
                    {
                        const float error = combine(referenceRow[x], features[x], cmax, pccmax);
                        if (error > errorRow[x])
                        {
                            errorRow[x] = error;
                        }
                    }
                }
            }
        }
    };

    // HDR-FLIP's exposures, as FLIP::evaluate steps them.
    inline float exposureAt(float start, float stop, int exposures, int i)
    {
        float exposureStepSize = (stop - start) / (exposures - 1);
        return start + i * exposureStepSize;
    }
}

extern "C"
{
    // Bumped whenever a signature or the features' layout changes (the loader checks it).
    int flip_native_abi(void) { return 2; }

    int flip_native_features_per_pixel(void) { return int(sizeof(Features) / sizeof(float)); }

    // The HDR-FLIP map (height x width floats) of two height x width x 3 linear-RGB images.
    void flip_hdr(const float* reference, const float* test, int width, int height, float ppd,
                  float start, float stop, int exposures, float* error_map)
    {
        FLIP::Parameters p;
        p.PPD = ppd;
        p.startExposure = start;
        p.stopExposure = stop;
        p.numExposures = exposures;
        p.tonemapper = "aces";
        float mean = -1.0f;
        float* map = nullptr;
        FLIP::evaluate(reference, test, width, height, true, p, false, false, mean, &map);
        std::memcpy(error_map, map, sizeof(float) * size_t(width) * height);
        delete[] map;
    }

    // The reference's half: features (exposures x height x width x flip_native_features_per_pixel floats).
    // `threads`: OpenMP threads (0: OpenMP's default), here and below.
    void flip_reference_features(const float* reference, int width, int height, float ppd,
                                 float start, float stop, int exposures, float* features, int threads)
    {
        Half half(width, height, ppd);
        for (int i = 0; i < exposures; i++)
        {
            half.compute(reference, exposureAt(start, stop, exposures, i),
                         reinterpret_cast<Features*>(features) + size_t(i) * width * height, nullptr, 0, 0, 0, nullptr, threads);
        }
    }

    // The map on a crop of the test image (crop_height x crop_width x 3, top-left at x0, y0 of the
    // reference's width x height) against the reference's features: error_map (crop_height x crop_width)
    // holds the maximum over exposures. Only pixels whose filter windows lie inside the crop (or
    // reach the image edge with it) are those of the whole image's map: the caller keeps those.
    void flip_against_reference(const float* features, int width, int height, const float* test, int x0, int y0,
                                int crop_width, int crop_height, float ppd, float start, float stop, int exposures,
                                float* error_map, int threads)
    {
        Half half(crop_width, crop_height, ppd);
        std::fill(error_map, error_map + size_t(crop_width) * crop_height, 0.0f);
        for (int i = 0; i < exposures; i++)
        {
            const Features* referenceFeatures = reinterpret_cast<const Features*>(features) + size_t(i) * width * height;
            half.compute(test, exposureAt(start, stop, exposures, i), nullptr, referenceFeatures, width, x0, y0, error_map, threads);
        }
    }
}
