//! Pose-format readers (SPEC.md §4a) on sequences our renderer writes in each format: COLMAP text
//! and binary, nerfstudio `transforms.json`, native 7-Scenes. Each reader is checked for a round
//! trip (camera and poses within 1e-12, frames reprojecting as the renderer's ground truth does
//! within 1e-6 px), its `inspect` summary, and malformed input (errors naming file and line, or
//! record and byte offset).

mod colmap;
#[path = "../common/mod.rs"]
mod common;
mod nerfstudio;
mod render;
mod sevenscenes;
