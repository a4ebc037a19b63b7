#include "mapper/mapper_params.h"

#include <stdexcept>

#include "common/params.h"

namespace radslam {

namespace {

void getFloat(ParamReader& r, const std::string& key, float* v) {
  double d = *v;
  r.get(key, &d);
  *v = static_cast<float>(d);
}

void getInt64(ParamReader& r, const std::string& key, int64_t* v) {
  double d = static_cast<double>(*v);
  r.get(key, &d);
  *v = static_cast<int64_t>(d);
}

}  // namespace

MapperNodeParams loadMapperParams(const std::string& yaml_path,
                                  const std::vector<std::string>& overrides, std::string* dump,
                                  std::string* source) {
  MapperNodeParams p;
  ParamReader r(yaml_path, "mapper");
  for (const std::string& o : overrides) r.addOverride(o);
  MapperParams& c = p.core;
  // Field.
  r.get("fine_voxel_size", &c.fine_voxel_size);
  r.get("fine_voxel_rel", &c.fine_voxel_rel);
  r.get("levels", &c.levels);
  r.get("level_ratio", &c.level_ratio);
  r.get("sh_degree", &c.sh_degree);
  r.get("density_bias", &c.density_bias);
  r.get("alloc_stride", &c.alloc_stride);
  getFloat(r, "alloc_sigma_range", &c.alloc_sigma_range);
  r.get("max_fine_blocks", &c.max_fine_blocks);
  getFloat(r, "alloc_max_depth_ratio", &c.alloc_max_depth_ratio);
  r.get("seed_density", &c.seed_density);
  r.get("seed_free_density", &c.seed_free_density);
  r.get("fill_depth_holes", &c.fill_depth_holes);
  r.get("exposure_init_stride", &c.exposure_init_stride);
  getFloat(r, "alloc_hole_sigmas", &c.alloc_hole_sigmas);
  getFloat(r, "alloc_max_band_voxels", &c.alloc_max_band_voxels);
  r.get("max_keyframes", &c.max_keyframes);
  // Training.
  TrainerParams& t = c.trainer;
  r.get("batch_rays", &t.batch_rays);
  r.get("patch_size", &t.patch_size);
  r.get("threads", &t.threads);
  int seed = static_cast<int>(t.seed);
  r.get("seed", &seed);
  t.seed = static_cast<uint64_t>(seed);
  r.get("surface_samples", &t.surface_samples);
  r.get("spread_samples", &t.spread_samples);
  r.get("free_samples", &t.free_samples);
  getFloat(r, "sigma_range", &t.sigma_range);
  getFloat(r, "sigma_min_voxels", &t.sigma_min_voxels);
  getFloat(r, "sigma_max_voxels", &t.sigma_max_voxels);
  getFloat(r, "near_voxels", &t.near_voxels);
  std::string depth_loss = depthLossName(t.depth_loss);
  r.get("depth_loss", &depth_loss);
  getFloat(r, "lambda_depth", &t.lambda_depth);
  getFloat(r, "raw_depth_sigma_voxels", &t.raw_depth_sigma_voxels);
  getFloat(r, "min_depth_sigma_voxels", &t.min_depth_sigma_voxels);
  getFloat(r, "depth_huber", &t.depth_huber);
  r.get("train_depthless_rays", &t.train_depthless_rays);
  getFloat(r, "lr_density", &t.adam.lr_density);
  getFloat(r, "lr_color", &t.adam.lr_color);
  getFloat(r, "coarse_lr_scale", &t.adam.coarse_lr_scale);
  r.get("lr_half_life_steps", &t.adam.lr_half_life_steps);
  getFloat(r, "lr_min_scale", &t.adam.lr_min_scale);
  getFloat(r, "adam_beta1", &t.adam.beta1);
  getFloat(r, "adam_beta2", &t.adam.beta2);
  r.get("refine_poses", &t.refine_poses);
  getFloat(r, "pose_lr_rot", &t.pose_lr_rot);
  getFloat(r, "pose_lr_trans_voxels", &t.pose_lr_trans_voxels);
  getInt64(r, "pose_warmup_rays", &t.pose_warmup_rays);
  getInt64(r, "pose_lr_half_life_steps", &t.pose_lr_half_life_steps);
  getFloat(r, "pose_depth_weight", &t.pose_depth_weight);
  r.get("refine_exposure", &t.refine_exposure);
  getFloat(r, "exposure_lr", &t.exposure_lr);
  getInt64(r, "exposure_warmup_rays", &t.exposure_warmup_rays);
  getFloat(r, "recency_boost", &t.recency_boost);
  getFloat(r, "recency_rays", &t.recency_rays);
  getFloat(r, "loss_boost", &t.loss_boost);
  // Rendering.
  getFloat(r, "render_step_fine", &c.render_step_fine);
  r.get("render_threads", &c.render_threads);
  // Node.
  r.get("update_period_s", &p.update_period_s);
  r.get("max_blocks_per_update", &p.max_blocks_per_update);
  std::string field_encoding = p.field_encoding == FieldEncoding::kZstd ? "zstd" : "raw";
  r.get("field_encoding", &field_encoding);
  if (field_encoding != "zstd" && field_encoding != "raw")
    throw std::invalid_argument("mapper: field_encoding must be zstd or raw, not '" +
                                field_encoding + "'");
  p.field_encoding = field_encoding == "zstd" ? FieldEncoding::kZstd : FieldEncoding::kRaw;
  r.get("status_period_s", &p.status_period_s);
  r.get("snapshot_min_period_s", &p.snapshot_min_period_s);
  r.get("field_max_mb_per_s", &p.field_max_mb_per_s);
  r.get("final_training_s", &p.final_training_s);
  r.get("final_rays_per_keyframe", &p.final_rays_per_keyframe);
  r.get("final_training_max_s", &p.final_training_max_s);
  r.get("final_training_threads", &p.final_training_threads);
  r.get("final_sync_s", &p.final_sync_s);
  r.get("checkpoint_images", &p.checkpoint_images);
  r.get("checkpoint_period_s", &p.checkpoint_period_s);
  r.get("render_stride", &p.render_stride);
  r.get("final_render_threads", &p.final_render_threads);
  getFloat(r, "mesh_iso", &p.mesh_iso);
  r.get("mesh_max_faces", &p.mesh_max_faces);
  r.get("publish_poses", &p.publish_poses);
  r.get("pose_publish_min_m", &p.pose_publish_min_m);
  r.get("pose_publish_min_deg", &p.pose_publish_min_deg);
  r.finish();
  t.depth_loss = parseDepthLoss(depth_loss);
  if (p.update_period_s <= 0 || p.status_period_s <= 0 || p.final_training_s < 0 ||
      !(p.final_sync_s >= 0) || !(p.pose_publish_min_m >= 0) || !(p.pose_publish_min_deg >= 0) ||
      p.render_stride < 1 || p.snapshot_min_period_s < 0 || p.max_blocks_per_update < 1 ||
      !(p.field_max_mb_per_s > 0) || !(p.checkpoint_period_s >= 0) || p.mesh_max_faces < 1 ||
      p.final_render_threads < 0 || p.final_rays_per_keyframe < 0 ||
      !(p.final_training_max_s >= p.final_training_s) || p.final_training_threads < 0)
    throw std::invalid_argument(
        "mapper: update_period_s and status_period_s must be > 0, final_training_s >= 0, "
        "final_rays_per_keyframe >= 0, final_training_max_s >= final_training_s, "
        "final_training_threads >= 0, "
        "final_sync_s >= 0, pose_publish_min_m and pose_publish_min_deg >= 0, "
        "render_stride >= 1, snapshot_min_period_s >= 0, max_blocks_per_update >= 1, "
        "field_max_mb_per_s > 0, checkpoint_period_s >= 0, mesh_max_faces >= 1, "
        "final_render_threads >= 0");
  if (dump) *dump = r.dump();
  if (source) *source = r.source();
  return p;
}

}  // namespace radslam
