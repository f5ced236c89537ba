//! The PSF database on the GPU: uploaded once per synthesizer, in the layout `common.wgsl`
//! reads (`DenseEntry`, the spreadlets' cumulative counts, positions and values) plus the
//! tiled splat's footprint table.

use psf_db::{DenseEntry, PsfDatabase, SPARSE_SLOT};

use super::tiles;
use super::util::storage_init;
use super::{GpuContext, GpuError};

/// The PSF database on the GPU.
pub(super) struct DbBuffers {
    pub(super) cumulative: wgpu::Buffer,
    pub(super) positions: wgpu::Buffer,
    pub(super) values: wgpu::Buffer,
    pub(super) dense_table: wgpu::Buffer,
    pub(super) dense_data: wgpu::Buffer,
    /// [`tiles::footprints`], on the GPU and here (entry counts are computed on the CPU).
    pub(super) footprints: wgpu::Buffer,
    pub(super) footprint_table: Vec<super::layout::PsfFootprint>,
    pub(super) psf_count: u32,
    pub(super) channels: u32,
    /// (PSFs, spreadlets, dense values): to tell a different database apart.
    pub(super) fingerprint: (usize, usize, usize),
}

impl DbBuffers {
    pub(super) fn upload(ctx: &GpuContext, db: Option<&PsfDatabase>) -> Result<Self, GpuError> {
        let Some(db) = db else {
            let empty = |l| storage_init(ctx, l, &[]);
            return Ok(Self {
                cumulative: empty("cumulative"),
                positions: empty("positions"),
                values: empty("values"),
                dense_table: empty("dense table"),
                dense_data: empty("dense data"),
                // At least one element: the binding holds 32-byte structs.
                footprints: storage_init(ctx, "footprints", &[0; 32]),
                footprint_table: Vec::new(),
                psf_count: 0,
                channels: 1,
                fingerprint: (0, 0, 0),
            });
        };
        let limit = ctx.limits().max_storage_buffer_binding_size;
        let check = |what: &'static str, bytes: usize| {
            if bytes as u64 > limit {
                Err(GpuError::TooLarge {
                    what,
                    bytes: bytes as u64,
                    limit,
                })
            } else {
                Ok(())
            }
        };
        check("database positions", 4 * db.positions().len())?;
        check("database values", 4 * db.values().len())?;
        check("database dense data", 4 * db.dense_data().len())?;
        // dense_slot resolved here: one entry per PSF, size 0 for sparse PSFs.
        let entries = db.dense_entries();
        let table: Vec<DenseEntry> = db
            .dense_slots()
            .iter()
            .map(|&s| {
                if s == SPARSE_SLOT {
                    DenseEntry::default()
                } else {
                    entries.get(s as usize).copied().unwrap_or_default()
                }
            })
            .collect();
        let footprint_table = tiles::footprints(db);
        check("footprints", 32 * footprint_table.len())?;
        Ok(Self {
            footprints: storage_init(
                ctx,
                "footprints",
                if footprint_table.is_empty() {
                    &[0; 32]
                } else {
                    bytemuck::cast_slice(&footprint_table)
                },
            ),
            footprint_table,
            cumulative: storage_init(ctx, "cumulative", bytemuck::cast_slice(db.cumulative())),
            positions: storage_init(ctx, "positions", bytemuck::cast_slice(db.positions())),
            values: storage_init(ctx, "values", bytemuck::cast_slice(db.values())),
            dense_table: storage_init(ctx, "dense table", bytemuck::cast_slice(&table)),
            dense_data: storage_init(ctx, "dense data", bytemuck::cast_slice(db.dense_data())),
            psf_count: db.psf_count() as u32,
            channels: db.channels() as u32,
            fingerprint: fingerprint(Some(db)),
        })
    }
}

/// (PSFs, spreadlets, dense values) of a database: to tell a different one apart.
pub(super) fn fingerprint(db: Option<&PsfDatabase>) -> (usize, usize, usize) {
    db.map_or((0, 0, 0), |d| {
        (d.psf_count(), d.spreadlet_count(), d.dense_data().len())
    })
}
