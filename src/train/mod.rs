//! Both stages' trainers and the adaptation of a models folder to labelled real frames
//! ([`adapt`]): stage 1 ([`stage1`]: §V-A-5 augmentation, resumable checkpoints, the
//! loss CSV, the manifest entry) on the native trainer ([`stage1::native`]) or candle's graph, ground-truth
//! sampling ([`gt_sampling`]), the transfer augmentation ([`transfer_aug`]), warm starts
//! ([`warm_start`]), AdamW ([`optim`]), checkpoints ([`checkpoint`]) and Result Fusion's
//! temperatures ([`temperature`]); the refiner's proposal database ([`proposals`]), its trainer
//! ([`refiner`], [`refiner_native`]) and loss ([`refiner_loss`]).

pub mod adapt;
pub mod checkpoint;
pub mod gt_sampling;
pub mod optim;
pub mod proposals;
pub mod refiner;
pub mod refiner_loss;
pub mod refiner_native;
pub mod stage1;
pub mod temperature;
pub mod transfer_aug;
pub mod warm_start;
