//! Fault details: the firmware writes them with `protocol::Detail` instead of `core::fmt`
//! (flash, issue 10). The texts must stay those of the errors' `Display` (the host reads the
//! same words either way): every variant is compared with its `Display`, and the one variant
//! the firmware writes differently on purpose (times to the millisecond, no float formatting)
//! is checked against the expected text.

use embedded_storage::nor_flash::NorFlashErrorKind;
use estimator_core::checkpoint::CheckpointError;
use estimator_core::FilterError;
use firmware_app::app::describe_filter_error;
use firmware_app::checkpoints::StoreError;
use firmware_app::resume::{describe_checkpoint_error, Msg};

fn checkpoint_text(e: CheckpointError) -> String {
    let mut m = Msg::new();
    describe_checkpoint_error(&e, &mut m);
    m.as_str().to_string()
}

fn filter_text(e: FilterError) -> String {
    let mut m = Msg::new();
    describe_filter_error(&e, &mut m);
    m.as_str().to_string()
}

#[test]
fn checkpoint_errors_read_as_their_display() {
    for e in [
        CheckpointError::BufferTooSmall { needed: 1234 },
        CheckpointError::Truncated,
        CheckpointError::BadMagic,
        CheckpointError::Version {
            found: 7,
            expected: 2,
        },
        CheckpointError::ModelMismatch {
            found: 0x0012_abcd,
            expected: 0xdead_beef,
        },
        CheckpointError::Crc,
        CheckpointError::Invalid,
    ] {
        // As the fault frame carries it: truncated to 80 bytes (the texts are ASCII).
        let display = e.to_string();
        assert_eq!(checkpoint_text(e), display[..display.len().min(80)]);
    }
}

#[test]
fn filter_errors_read_as_their_display() {
    for e in [
        FilterError::Capacity {
            needed: 27,
            capacity: 15,
        },
        FilterError::Dimension {
            expected: 3,
            got: 0,
        },
        FilterError::BadMeasurement { step: 0 },
        FilterError::SingularInnovation {
            step: 4_000_000_000,
        },
        FilterError::Unhealthy {
            step: 12,
            index: 14,
        },
        FilterError::RejectionRun {
            step: 39,
            count: 10,
        },
    ] {
        assert_eq!(filter_text(e), e.to_string());
    }
}

#[test]
fn filter_times_are_written_to_the_millisecond() {
    let text = |t_s, filter_t_s| {
        filter_text(FilterError::TimeNotIncreasing {
            step: 5,
            t_s,
            filter_t_s,
        })
    };
    assert_eq!(
        text(1.5, 1.5),
        "step 5: measurement at t = 1.500 s is not after the filter time 1.500 s"
    );
    // Truncated, not rounded; zero-padded milliseconds; the sign of a negative time.
    assert_eq!(
        text(-0.0429, 216_000.999_9),
        "step 5: measurement at t = -0.042 s is not after the filter time 216000.999 s"
    );
    // NaN writes as 0.000 (as the former `Display` of the firmware did).
    assert_eq!(
        text(f64::NAN, 10.0625),
        "step 5: measurement at t = 0.000 s is not after the filter time 10.062 s"
    );
}

#[test]
fn store_errors_have_their_texts() {
    let text = |e: StoreError| {
        let mut m = Msg::new();
        e.describe(&mut m);
        assert_eq!(m.as_str(), e.to_string());
        e.to_string()
    };
    assert_eq!(
        text(StoreError::Flash(NorFlashErrorKind::OutOfBounds)),
        "flash error OutOfBounds"
    );
    assert_eq!(
        text(StoreError::Flash(NorFlashErrorKind::NotAligned)),
        "flash error NotAligned"
    );
    assert_eq!(
        text(StoreError::Format { found: 9 }),
        format!(
            "checkpoint record format 9, this firmware reads {}",
            firmware_app::checkpoints::FORMAT
        )
    );
}
